"""``POST /v1/match/bundle``: one match, answered with /v1/match's JSON and the bytes of every single endpoint."""
from __future__ import annotations

import base64
import struct

import cv2
import numpy as np
import pytest

from service import problems as P
from service.routes.bundle import BUNDLE_FILES

FAST = {"max_keypoints": "800", "seed": "3"}  # with the dense stage: its confidence map is one of the files
PATH = "/v1/match/bundle"


def encode(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    assert ok
    return buf.tobytes()


def files_of(png_pair, b=None):
    return {"image_a": ("a.png", png_pair[0], "image/png"), "image_b": ("b.png", png_pair[1] if b is None else b,
                                                                      "image/png")}


def post(client, path, png_pair, fields=None, b=None):
    return client.post(path, files=files_of(png_pair, b), data={**FAST, **(fields or {})})


@pytest.fixture(scope="module")
def bundle(client, png_pair):
    r = post(client, PATH, png_pair, {"alpha": "0.3"})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/json"
    body = r.json()
    return body["match"], {name: base64.b64decode(data, validate=True) for name, data in body["files"].items()}


def _png(data: bytes) -> np.ndarray:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None
    return image


def test_bundle_has_the_match_and_every_file_in_a_frame(client, bundle, png_pair, image_pair):
    match, files = bundle
    assert set(files) == set(BUNDLE_FILES)  # the match has a confidence map: every file is there
    height, width = image_pair[0].shape[:2]
    assert match["shape_a"] == [height, width] and match["seed"] == 3
    assert match["converged"] is True and match["n_inliers"] > 50
    for name in ("warped.png", "overlay.png", "flow.png"):
        assert _png(files[name]).shape == (height, width, 3), name
    assert _png(files["confidence.png"]).shape == (height, width)
    flo = files["flow.flo"]
    assert flo[:4] == b"PIEH" and struct.unpack("<ii", flo[4:12]) == (width, height)
    assert len(flo) == 12 + height * width * 2 * 4


def test_bundle_equals_the_single_endpoints(client, bundle, png_pair):
    match, files = bundle
    single = post(client, "/v1/match", png_pair)
    assert single.status_code == 200, single.text
    want = single.json()
    # the same match, key for key (timings are measured anew, but name the same stages)
    assert set(match["timings_ms"]) == set(want.pop("timings_ms"))
    assert {k: v for k, v in match.items() if k != "timings_ms"} == want
    asked = {"warped.png": ("/v1/warp", {}), "overlay.png": ("/v1/warp", {"overlay": "true", "alpha": "0.3"}),
             "flow.png": ("/v1/flow", {"format": "png"}), "flow.flo": ("/v1/flow", {"format": "flo"}),
             "confidence.png": ("/v1/confidence", {"format": "png"})}
    for name, (path, fields) in asked.items():
        r = post(client, path, png_pair, fields)
        assert r.status_code == 200, (name, r.text)
        assert files[name] == r.content, name


def test_alpha_weights_the_overlay(client, bundle, png_pair, image_pair):
    _, files = bundle
    r = post(client, PATH, png_pair, {"alpha": "1"})
    assert r.status_code == 200, r.text
    full = base64.b64decode(r.json()["files"]["overlay.png"])
    # alpha 1 shows warped b only: the overlay is warped.png; at 0.3 it is not
    np.testing.assert_array_equal(_png(full), _png(files["warped.png"]))
    assert not np.array_equal(_png(files["overlay.png"]), _png(files["warped.png"]))


def test_no_confidence_map_no_confidence_file(client, png_pair):
    r = post(client, PATH, png_pair, {"features": "shape_context"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["match"]["features"] == "shape_context" and body["match"]["confidence"] is None
    assert set(body["files"]) == set(BUNDLE_FILES) - {"confidence.png"}


def test_not_converged_is_a_200_with_its_reason(client, png_pair, image_pair):
    grey = encode(np.full_like(image_pair[1], 128))  # no keypoints in b
    r = post(client, PATH, png_pair, b=grey)
    assert r.status_code == 200, r.text
    match = r.json()["match"]
    assert match["converged"] is False and match["reason"] == "too_few_matches" and match["n_inliers"] == 0


def _problem(r, status, type_):
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(P.MEDIA_TYPE)
    body = r.json()
    assert body["type"] == type_ and body["status"] == status
    assert "Traceback" not in r.text
    return body


@pytest.mark.parametrize(("fields", "named"), [
    ({"alpah": "0.3"}, "alpah"),            # misspelled: never silently ignored
    ({"alpha": "1.5"}, "alpha"),            # out of [0, 1]
    ({"overlay": "true"}, "overlay"),       # a field of /v1/warp, not of the bundle
    ({"ratio": "2"}, "ratio"),              # a match field out of range
    ({"max_keypoints": str(10**6)}, "max_keypoints"),  # over the service's limit
])
def test_bad_fields_are_422_naming_the_field(client, png_pair, fields, named):
    body = _problem(post(client, PATH, png_pair, fields), 422, P.INVALID_INPUT)
    assert named in body["detail"]


def test_bad_images_are_refused_as_elsewhere(client, png_pair, settings):
    body = _problem(post(client, PATH, png_pair, b=b"this is text, not an image\n"), 400, P.UNDECODABLE_IMAGE)
    assert "image_b" in body["detail"]
    r = client.post(PATH, files={"image_a": ("a.png", png_pair[0], "image/png")}, data=FAST)
    assert "image_b" in _problem(r, 422, P.INVALID_INPUT)["detail"]
    side = int(np.sqrt(settings.max_pixels)) + 10  # over the pixel limit, read from the header
    big = encode(np.zeros((side, side), np.uint8))
    _problem(post(client, PATH, png_pair, b=big), 413, P.TOO_LARGE)


def test_bundle_has_the_upload_limits(client, png_pair, settings):
    """The request guard covers the bundle as it covers /v1/match: bytes over the limit and bodies that are not
    multipart are refused before they are read."""
    over = b"\x89PNG\r\n\x1a\n" + bytes(settings.max_upload_bytes)
    _problem(post(client, PATH, png_pair, b=over), 413, P.TOO_LARGE)
    _problem(client.post(PATH, json={"image_a": "a"}), 415, P.UNSUPPORTED_FORMAT)


def test_bundle_is_documented(client):
    doc = client.get("/openapi.json").json()
    post_doc = doc["paths"][PATH]["post"]
    props = post_doc["requestBody"]["content"]["multipart/form-data"]["schema"]["properties"]
    assert {"image_a", "image_b", "features", "method", "dense", "seed", "alpha"} <= set(props)
    assert "overlay" not in props and "format" not in props
    assert {"422", "413", "429"} <= set(post_doc["responses"])
