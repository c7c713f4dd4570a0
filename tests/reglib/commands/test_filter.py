"""Tests of the ``reglib filter`` command (run in-process through reglib.cli.main)."""
import json

import numpy as np
import pytest

from reglib import FilterResult, filter_matches
from reglib.cli import main


def _matches(n=120, seed=0):
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 400, (n, 2))
    dst = src * 1.1 + [15.0, -8.0] + 4 * np.sin(src[:, ::-1] / 90)
    bad = np.arange(n) % 4 == 0
    dst[bad] = rng.uniform(0, 400, (int(bad.sum()), 2))
    return src, dst, ~bad


def test_text_matches_give_the_library_json(tmp_path, capsys):
    src, dst, good = _matches()
    np.savetxt(tmp_path / "m.txt", np.c_[src, dst])
    out = tmp_path / "f.json"
    assert main(["filter", str(tmp_path / "m.txt"), "--out", str(out), "--seed", "4"]) == 0
    body = json.loads(out.read_text())
    want = filter_matches(src, dst, rng=4).to_dict()
    assert set(body) == set(want)
    assert body["inliers"] == want["inliers"] and body["n_iter"] == want["n_iter"] and body["seed"] == 4
    np.testing.assert_allclose(body["scores"], want["scores"], rtol=1e-9)
    inliers = FilterResult.from_dict(body).inliers
    assert inliers[good].mean() > 0.95 and inliers[~good].mean() < 0.05
    assert f"{int(good.sum())}/" in capsys.readouterr().out or body["n_inliers"] > 0


def test_npz_3d_vfc_with_options(tmp_path):
    rng = np.random.default_rng(1)
    src = rng.uniform(0, 1, (80, 3))
    dst = src + [0.1, 0.0, -0.2]
    np.savez(tmp_path / "m.npz", src=src, dst=dst)
    out = tmp_path / "f.json"
    assert main(["filter", str(tmp_path / "m.npz"), "--out", str(out), "--method", "vfc",
                 "--options", '{"outlier_volume": 5}']) == 0
    body = json.loads(out.read_text())
    assert body["method"] == "vfc" and body["n_inliers"] == 80


@pytest.mark.parametrize("content, options, words", [
    ("1 2 3\n4 5 6\n", None, "columns"),
    ("1 2 3 4\n", '{"a": 3}', "renamed to `outlier_volume`"),
    ("1 2 3 4\n", "{not json", "--options"),
])
def test_bad_input_exits_2(tmp_path, capsys, content, options, words):
    (tmp_path / "m.txt").write_text(content)
    argv = ["filter", str(tmp_path / "m.txt"), "--out", str(tmp_path / "o.json"), "--method", "vfc"]
    if options:
        argv += ["--options", options]
    assert main(argv) == 2
    assert words in capsys.readouterr().err


def test_a_csv_with_a_header_row_is_read(tmp_path, capsys):
    src, dst, _ = _matches(60)
    rows = "\n".join(",".join(repr(float(v)) for v in row) for row in np.c_[src, dst])
    (tmp_path / "m.csv").write_text("x_a,y_a,x_b,y_b\n" + rows + "\n")
    out = tmp_path / "f.json"
    assert main(["filter", str(tmp_path / "m.csv"), "--out", str(out)]) == 0
    body = json.loads(out.read_text())
    assert body["n_matches"] == 60 and body["inliers"] == filter_matches(src, dst, rng=0).to_dict()["inliers"]


def test_an_npz_with_the_wrong_keys_names_the_keys_it_needs(tmp_path, capsys):
    np.savez(tmp_path / "m.npz", a=np.zeros((5, 2)), b=np.zeros((5, 2)))
    assert main(["filter", str(tmp_path / "m.npz"), "--out", str(tmp_path / "f.json")]) == 2
    err = capsys.readouterr().err
    assert "needs arrays `src` and `dst`" in err and "it holds ['a', 'b']" in err and "not a readable" not in err
