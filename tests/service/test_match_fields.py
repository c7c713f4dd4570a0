"""Every field of a match request (features, method, seed, each MatchOptions field) reaches the service
form, its OpenAPI schema and batch manifests with the library's bounds (derived, not copied)."""
from __future__ import annotations

import pytest

from reglib.batch._manifest import check_options
from reglib.errors import InputError
from reglib.matching import match_request_specs
from service.problems import INVALID_INPUT

SPECS = match_request_specs()


def _beyond(spec):
    return int(spec.high) + 1 if spec.kind == "int" else spec.high * 2 + 1.0


def test_openapi_lists_every_field_with_its_bounds(client, settings):
    doc = client.get("/openapi.json").json()
    for path in ("/v1/match", "/v1/warp", "/v1/flow"):
        props = doc["paths"][path]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]["properties"]
        for spec in SPECS:
            assert spec.name in props, (path, spec.name)
            prop = props[spec.name]
            high = {"max_pixels": settings.max_pixels, "max_keypoints": settings.max_keypoints_limit}.get(spec.name,
                                                                                                          spec.high)
            if spec.kind in ("int", "float") and spec.high is not None:
                assert prop.get("maximum", prop.get("exclusiveMaximum")) == high, spec.name
            if spec.kind in ("int", "float") and spec.low is not None:
                assert prop.get("minimum", prop.get("exclusiveMinimum")) == spec.low, spec.name


@pytest.mark.parametrize("spec", [s for s in SPECS if s.kind in ("int", "float") and s.high is not None],
                         ids=lambda s: s.name)
def test_form_refuses_a_value_beyond_the_bound_naming_it(client, png_pair, spec):
    a, b = png_pair
    files = {"image_a": ("a.png", a, "image/png"), "image_b": ("b.png", b, "image/png")}
    r = client.post("/v1/match", files=files, data={spec.name: str(_beyond(spec))})
    assert r.status_code == 422, r.text
    assert r.json()["type"] == INVALID_INPUT and f"`{spec.name}`" in r.json()["detail"]


def test_form_takes_the_service_bounds_where_stricter(client, png_pair, settings):
    a, b = png_pair
    files = {"image_a": ("a.png", a, "image/png"), "image_b": ("b.png", b, "image/png")}
    for name, limit in (("max_pixels", settings.max_pixels), ("max_keypoints", settings.max_keypoints_limit)):
        r = client.post("/v1/match", files=files, data={name: str(limit + 1)})
        assert r.status_code == 422 and f"`{name}`" in r.json()["detail"], r.text


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.name)
def test_manifest_takes_every_field_with_its_bounds(spec):
    valid = {"bool": "true", "json": "{}", "choice": spec.default}.get(spec.kind, str(spec.default))
    assert set(check_options({spec.name: valid})) == {spec.name}
    if spec.kind in ("int", "float") and spec.high is not None:
        with pytest.raises(InputError, match=f"`{spec.name}`"):
            check_options({spec.name: str(_beyond(spec))})
