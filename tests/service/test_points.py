"""/v1/filter and /v1/register answer exactly what the library answers for the same input and seed."""
from __future__ import annotations

import json

import numpy as np
import pytest

import reglib
from reglib.cli import main
from service.problems import INVALID_INPUT, MEDIA_TYPE


def _synthetic(n=200, seed=0, dim=2):
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 400, (n, dim))
    dst = src * 1.03 + 7.0 + 6.0 * np.sin(src[:, ::-1] / 90.0)
    bad = rng.random(n) < 0.3
    dst[bad] = rng.uniform(0, 400, (int(bad.sum()), dim))
    return src, dst


def _same(answer: dict, expected: dict) -> None:
    """Equal JSON, floats to 1e-9 relative (CONTRACTS.md, Determinism)."""
    assert set(answer) == set(expected)
    for key, value in expected.items():
        got = answer[key]
        if isinstance(value, dict):
            _same(got, value)
        elif isinstance(value, list) and value and not isinstance(np.asarray(value, dtype=object).flat[0], str):
            np.testing.assert_allclose(np.asarray(got, dtype=float), np.asarray(value, dtype=float), rtol=1e-9, atol=0)
        else:
            assert got == value, key


@pytest.mark.parametrize("method", ["l2e", "vfc"])
@pytest.mark.parametrize("seed", [0, 7])
def test_filter_equals_library(client, method, seed):
    src, dst = _synthetic(seed=seed)
    body = {"src": src.tolist(), "dst": dst.tolist(), "method": method, "seed": seed}
    r = client.post("/v1/filter", json=body)
    assert r.status_code == 200, r.text
    answer = r.json()
    expected = reglib.filter_matches(src, dst, method=method, rng=seed).to_dict()
    assert answer.pop("timings_ms").keys() == {"filter"}
    _same(answer, json.loads(json.dumps(expected)))
    assert answer["inliers"] == sorted(answer["inliers"])
    assert answer["n_inliers"] == len(answer["inliers"])


def test_filter_default_seed_is_zero_and_options_pass_through(client):
    src, dst = _synthetic(seed=3)
    r = client.post("/v1/filter", json={"src": src.tolist(), "dst": dst.tolist(), "options": {"linear": "affine"}})
    assert r.status_code == 200, r.text
    expected = reglib.filter_matches(src, dst, options={"linear": "affine"}, rng=0)
    assert r.json()["seed"] == 0
    assert r.json()["inliers"] == np.flatnonzero(expected.inliers).tolist()
    assert r.json()["transform"] == json.loads(json.dumps(expected.transform.to_dict()))


def test_filter_3d(client):
    src, dst = _synthetic(n=150, dim=3)
    r = client.post("/v1/filter", json={"src": src.tolist(), "dst": dst.tolist(), "seed": 1})
    assert r.status_code == 200, r.text
    expected = reglib.filter_matches(src, dst, rng=1)
    assert r.json()["inliers"] == np.flatnonzero(expected.inliers).tolist()
    assert r.json()["transform"]["dim"] == 3


def test_filter_too_few_is_an_answer(client):
    r = client.post("/v1/filter", json={"src": [], "dst": []})
    assert r.status_code == 200, r.text
    j = r.json()
    assert j["n_matches"] == 0 and j["inliers"] == [] and j["converged"] is False and j["reason"]


def test_filter_unknown_option_is_422_naming_it(client):
    src, dst = _synthetic(n=20)
    r = client.post("/v1/filter", json={"src": src.tolist(), "dst": dst.tolist(), "options": {"betaa": 1}})
    assert r.status_code == 422
    assert r.headers["content-type"].startswith(MEDIA_TYPE)
    assert r.json()["type"] == INVALID_INPUT and "betaa" in r.json()["detail"]


@pytest.mark.parametrize("method", ["l2e", "cpd"])
def test_register_equals_library(client, method):
    rng = np.random.default_rng(5)
    model = rng.uniform(0, 100, (80, 2))
    target = model * 1.05 + [4.0, -3.0] + 2.0 * np.sin(model[:, ::-1] / 30.0)
    r = client.post("/v1/register", json={"model": model.tolist(), "target": target.tolist(), "method": method,
                                          "seed": 2})
    assert r.status_code == 200, r.text
    expected = reglib.register_points(model, target, method=method, rng=2).to_dict()
    answer = r.json()
    assert answer.pop("timings_ms").keys() == {"register"}
    _same(answer, json.loads(json.dumps(expected)))
    assert np.asarray(r.json()["registered"]).shape == (80, 2)


@pytest.mark.parametrize("method", ["l2e", "vfc"])
def test_cli_filter_and_the_service_give_the_same_json(client, tmp_path, method):
    src, dst = _synthetic(seed=11)
    np.savetxt(tmp_path / "m.txt", np.c_[src, dst], fmt="%.17g")
    assert main(["filter", str(tmp_path / "m.txt"), "--out", str(tmp_path / "f.json"), "--method", method,
                 "--seed", "5"]) == 0
    r = client.post("/v1/filter", json={"src": src.tolist(), "dst": dst.tolist(), "method": method, "seed": 5})
    assert r.status_code == 200, r.text
    answer = r.json()
    answer.pop("timings_ms")
    _same(answer, json.loads((tmp_path / "f.json").read_text()))


@pytest.mark.parametrize("method", ["l2e", "cpd-rigid"])
def test_cli_register_and_the_service_give_the_same_json(client, tmp_path, method):
    rng = np.random.default_rng(8)
    model = rng.uniform(0, 100, (60, 2))
    target = model * 1.05 + [4.0, -3.0] + 1.5 * np.sin(model[:, ::-1] / 30.0)
    np.savetxt(tmp_path / "m.txt", model, fmt="%.17g")
    np.savetxt(tmp_path / "t.txt", target, fmt="%.17g")
    assert main(["register", str(tmp_path / "m.txt"), str(tmp_path / "t.txt"), "--out", str(tmp_path / "r.json"),
                 "--method", method, "--seed", "3"]) == 0
    r = client.post("/v1/register", json={"model": model.tolist(), "target": target.tolist(), "method": method,
                                          "seed": 3})
    assert r.status_code == 200, r.text
    answer = r.json()
    answer.pop("timings_ms")
    _same(answer, json.loads((tmp_path / "r.json").read_text()))


def test_register_an_organized_scan_with_null_pixels(client):
    rng = np.random.default_rng(2)
    grid = rng.uniform(-1, 1, (12, 15, 3)) * [1.0, 0.7, 0.4]
    target = grid.reshape(-1, 3) + [0.05, -0.02, 0.03]
    rows = grid.tolist()
    rows[0][0] = None
    rows[3][4] = None
    r = client.post("/v1/register", json={"model": rows, "target": target.tolist(), "method": "icp", "seed": 0})
    assert r.status_code == 200, r.text
    body = r.json()
    assert len(body["correspondence"]) == 12 * 15 and len(body["registered"]) == 12 * 15
    assert body["registered"][0] is None and body["correspondence"][0] == -1
    got = np.asarray([p for p in body["registered"] if p is not None])
    assert np.abs(got - np.delete(target, [0, 3 * 15 + 4], axis=0)).max() < 1e-3
