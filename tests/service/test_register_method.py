"""``/v1/register`` names a bad ``method`` in the library's words, as the image endpoints name a bad ``features``."""
from __future__ import annotations

import numpy as np
import pytest

import reglib
from reglib.errors import InputError
from reglib.registration import METHODS
from service import problems as P

MODEL = np.random.default_rng(3).uniform(-1.0, 1.0, (30, 2))


def _library_message(method: str) -> str:
    with pytest.raises(InputError) as info:
        reglib.register_points(MODEL, MODEL, method=method)  # type: ignore[arg-type]
    return str(info.value)


@pytest.mark.parametrize("method", ["ransac", "ICP", ""])
def test_an_unknown_method_is_a_422_in_the_library_words(client, method):
    r = client.post("/v1/register", json={"model": MODEL.tolist(), "target": MODEL.tolist(), "method": method})
    assert r.status_code == 422 and r.headers["content-type"].startswith(P.MEDIA_TYPE)
    body = r.json()
    assert body["type"] == P.INVALID_INPUT
    assert body["detail"] == f"`method` must be one of {list(METHODS)}, got {method!r}"
    assert body["detail"] == _library_message(method)


def test_the_image_endpoints_word_a_bad_features_the_same_way(client, png_pair):
    r = client.post("/v1/match", files={"image_a": ("a.png", png_pair[0]), "image_b": ("b.png", png_pair[1])},
                    data={"features": "orb"})
    assert r.status_code == 422 and r.json()["detail"].startswith("`features` must be one of [")


def test_a_method_that_is_not_a_string_is_still_a_422(client):
    r = client.post("/v1/register", json={"model": MODEL.tolist(), "target": MODEL.tolist(), "method": 5})
    assert r.status_code == 422 and r.json()["type"] == P.INVALID_INPUT


def test_the_openapi_schema_still_lists_the_methods(client):
    schema = client.get("/openapi.json").json()["components"]["schemas"]["RegisterRequest"]
    assert schema["properties"]["method"]["enum"] == list(METHODS)
    assert schema["properties"]["method"]["default"] == "l2e"


def test_a_good_method_still_registers(client):
    target = MODEL * 1.1 + [0.3, -0.2]
    r = client.post("/v1/register", json={"model": MODEL.tolist(), "target": target.tolist(), "method": "cpd-affine",
                                          "seed": 0})
    assert r.status_code == 200 and r.json()["method"] == "cpd-affine"
    assert np.abs(np.asarray(r.json()["registered"]) - target).max() < 1e-3


def test_a_bad_filter_method_is_answered_in_the_library_words(client):
    body = {"src": [[0.0, 0.0]] * 10, "dst": [[1.0, 1.0]] * 10, "method": "ransac"}
    r = client.post("/v1/filter", json=body)
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
    assert r.json()["detail"] == "`method` must be one of ['l2e', 'vfc'], got 'ransac'"
    assert client.app.openapi()["components"]["schemas"]["FilterRequest"]["properties"]["method"]["enum"] == [
        "l2e", "vfc"]
