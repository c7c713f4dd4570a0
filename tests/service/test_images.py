"""/v1/match, /v1/warp and /v1/flow answer what the library answers for the same images and seed."""
from __future__ import annotations

import io
import json

import numpy as np
import pytest

import reglib
from reglib.io import read_image

FAST = {"dense": "false", "max_keypoints": "800"}  # the dense stage is slow; it has its own library tests


def library_match(png_pair, settings, seed=0, method="l2e", **options):
    a = read_image(png_pair[0], max_pixels=settings.max_pixels)
    b = read_image(png_pair[1], max_pixels=settings.max_pixels)
    opts = {"dense": False, "max_keypoints": 800, "max_pixels": settings.max_pixels, **options}
    return a, b, reglib.match_images(a, b, method=method, options=opts, rng=seed)


def post(client, path, png_pair, fields=None, **kw):
    files = {"image_a": ("a.png", png_pair[0], "image/png"), "image_b": ("b.png", png_pair[1], "image/png")}
    return client.post(path, files=files, data={**FAST, **(fields or {})}, **kw)


@pytest.mark.parametrize(("seed", "method"), [(0, "l2e"), (5, "vfc")])
def test_match_equals_library(client, settings, png_pair, seed, method):
    r = post(client, "/v1/match", png_pair, {"seed": str(seed), "method": method})
    assert r.status_code == 200, r.text
    answer = r.json()
    _, _, expected = library_match(png_pair, settings, seed=seed, method=method)
    want = json.loads(json.dumps(expected.to_dict()))
    assert answer["seed"] == seed
    for key in ("n_matches", "n_inliers", "inliers", "converged", "reason", "shape_a", "shape_b"):
        assert answer[key] == want[key], key
    for key in ("src", "dst", "scores", "fold_fraction"):
        np.testing.assert_allclose(answer[key], want[key], rtol=1e-9, atol=0)
    assert answer["transform"] == want["transform"]
    assert answer["n_inliers"] > 50
    assert "decode" in answer["timings_ms"]


def test_match_options_reach_the_library(client, settings, png_pair):
    r = post(client, "/v1/match", png_pair, {"ratio": "0.6", "mutual": "true", "filter": '{"linear": "affine"}'})
    assert r.status_code == 200, r.text
    _, _, expected = library_match(png_pair, settings, ratio=0.6, mutual=True, filter={"linear": "affine"})
    assert r.json()["n_matches"] == expected.n_matches
    assert r.json()["inliers"] == np.flatnonzero(expected.inliers).tolist()


@pytest.mark.parametrize("overlay", [False, True])
def test_warp_equals_library(client, settings, png_pair, overlay):
    from reglib.visualize import overlay as blend

    r = post(client, "/v1/warp", png_pair, {"overlay": str(overlay).lower(), "alpha": "0.3"})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png"
    a, b, match = library_match(png_pair, settings)
    warped, _ = reglib.warp_image(b, match.transform, a.shape[:2], interpolation="linear")
    want = blend(a, warped, 0.3) if overlay else warped
    got = read_image(r.content)
    assert got.shape == want.shape
    assert np.array_equal(got, np.asarray(want).astype(got.dtype))


@pytest.mark.parametrize(("how", "fmt"), [({"data": {"format": "npy"}}, "npy"),
                                          ({"headers": {"accept": "application/x-flo"}}, "flo"),
                                          ({"params": {"format": "png"}}, "png"),
                                          ({}, "npy")])
def test_flow_equals_library(client, settings, png_pair, how, fmt):
    from reglib.visualize import flow_to_color

    files = {"image_a": ("a.png", png_pair[0], "image/png"), "image_b": ("b.png", png_pair[1], "image/png")}
    r = client.post("/v1/flow", files=files, data={**FAST, **how.get("data", {})}, headers=how.get("headers"),
                    params=how.get("params"))
    assert r.status_code == 200, r.text
    a, _, match = library_match(png_pair, settings)
    flow = reglib.dense_flow(match.transform, a.shape[:2])
    if fmt == "npy":
        got = np.load(io.BytesIO(r.content), allow_pickle=False)
        assert got.dtype == np.float32 and np.array_equal(got, flow)
    elif fmt == "flo":
        assert r.content[:4] == b"PIEH"
        w, h = np.frombuffer(r.content[4:12], "<i4")
        assert (h, w) == a.shape[:2]
        assert np.array_equal(np.frombuffer(r.content[12:], "<f4").reshape(h, w, 2), flow)
    else:
        assert np.array_equal(read_image(r.content), flow_to_color(flow))


def test_jpeg_upload(client, settings, image_pair):
    import cv2

    pair = tuple(cv2.imencode(".jpg", cv2.cvtColor(im, cv2.COLOR_RGB2BGR))[1].tobytes() for im in image_pair)
    r = post(client, "/v1/match", pair)
    assert r.status_code == 200, r.text
    _, _, expected = library_match(pair, settings)
    assert r.json()["inliers"] == np.flatnonzero(expected.inliers).tolist()


def test_confidence_endpoint_is_the_librarys_map(client, png_pair):
    a, b = png_pair
    files = {"image_a": ("a.png", a, "image/png"), "image_b": ("b.png", b, "image/png")}
    r = client.post("/v1/confidence", files=files, data={"format": "npy", "seed": "0"})
    assert r.status_code == 200, r.text
    got = np.load(__import__("io").BytesIO(r.content))
    match = reglib.match_images(read_image(a), read_image(b), rng=0, options={"max_pixels": 2_000_000})
    assert got.shape == match.shape_a and got.dtype == np.float32
    np.testing.assert_allclose(got, match.confidence, atol=1e-6)
    png = client.post("/v1/confidence", files=files, data={"format": "png"})
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
