"""/v1/flow's ITK displacement-field formats: the bytes reglib.io.write_flow writes, which SimpleITK reads."""
from __future__ import annotations

import numpy as np
import pytest

import reglib
from reglib.io import encode_flow, read_flow, read_image
from reglib.outputs import FLOW_FORMATS

FAST = {"dense": "false", "max_keypoints": "800"}


def _post(client, png_pair, **kw):
    files = {"image_a": ("a.png", png_pair[0], "image/png"), "image_b": ("b.png", png_pair[1], "image/png")}
    return client.post("/v1/flow", files=files, **kw)


def _library_flow(png_pair, settings):
    a = read_image(png_pair[0], max_pixels=settings.max_pixels)
    b = read_image(png_pair[1], max_pixels=settings.max_pixels)
    match = reglib.match_images(a, b, options={"dense": False, "max_keypoints": 800,
                                               "max_pixels": settings.max_pixels}, rng=0)
    return match, reglib.dense_flow(match.transform, a.shape[:2])


@pytest.mark.parametrize("fmt, where", [("mha", "data"), ("nrrd", "params"), ("nii.gz", "data"), ("nii", "params")])
def test_flow_as_an_itk_displacement_field(client, settings, png_pair, tmp_path, fmt, where):
    r = _post(client, png_pair, data=FAST | ({"format": fmt} if where == "data" else {}),
              params={"format": fmt} if where == "params" else None)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/octet-stream"
    assert r.headers["content-disposition"] == f'attachment; filename="flow.{fmt}"'
    match, flow = _library_flow(png_pair, settings)
    assert r.content == encode_flow(flow, f".{fmt}")  # the library's file, byte for byte
    (tmp_path / f"flow.{fmt}").write_bytes(r.content)
    assert np.array_equal(read_flow(tmp_path / f"flow.{fmt}"), flow)

    sitk = pytest.importorskip("SimpleITK")
    field = sitk.Cast(sitk.ReadImage(str(tmp_path / f"flow.{fmt}")), sitk.sitkVectorFloat64)
    itk_transform = sitk.DisplacementFieldTransform(field)
    points = np.array([[10.0, 20.0], [100.0, 50.0], [200.0, 150.0]])  # pixel centres (x = column, y = row)
    got = np.array([itk_transform.TransformPoint(tuple(p)) for p in points])
    assert np.abs(got - match.transform(points)).max() < 0.05  # dense_flow's budget (CONTRACTS.md)


def test_an_unknown_format_is_a_422_listing_every_flow_format(client, png_pair):
    r = _post(client, png_pair, data=FAST | {"format": "tiff"})
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
    assert all(f"'{fmt}'" in r.text for fmt in (*FLOW_FORMATS, "png")), r.text


def test_the_schema_offers_the_cli_s_flow_formats_and_png(client):
    """One list: what /v1/flow takes is reglib match's --flow-format choices plus its picture."""
    schema = client.get("/openapi.json").json()
    body = schema["paths"]["/v1/flow"]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]
    fmt = body["properties"]["format"]
    offered = next(v["enum"] for v in fmt.get("anyOf", [fmt]) if "enum" in v)
    assert sorted(offered) == sorted((*FLOW_FORMATS, "png"))
