"""What callers may pass (images, points, options) and how arrays come back from files."""
from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np
import pytest

from reglib_client import decode_png
from reglib_client._arrays import decode_flow, decode_image
from reglib_client._inputs import form_fields, image_part, json_options, points_json


def test_image_part_from_every_kind_of_input(tmp_path: Path) -> None:
    jpeg = b"\xff\xd8\xff\xe0" + b"\x00" * 20
    path = tmp_path / "photo.jpg"
    path.write_bytes(jpeg)
    assert image_part(path, "image_a") == ("photo.jpg", jpeg, "image/jpeg")
    assert image_part(str(path), "image_a") == ("photo.jpg", jpeg, "image/jpeg")
    assert image_part(bytearray(jpeg), "image_b") == ("image_b.jpg", jpeg, "image/jpeg")
    stream = io.BytesIO(b"xx" + jpeg)
    stream.read(2)  # read from the current position
    assert image_part(stream, "image_a") == ("image_a.jpg", jpeg, "image/jpeg")
    with open(path, "rb") as handle:
        assert image_part(handle, "image_a") == ("photo.jpg", jpeg, "image/jpeg")
    array = np.arange(30, dtype=np.uint8).reshape(5, 6)
    name, data, media = image_part(array, "image_b")
    assert (name, media) == ("image_b.png", "image/png")
    np.testing.assert_array_equal(decode_png(data), array)


def test_image_part_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        image_part(tmp_path / "missing.png", "image_a")
    with pytest.raises(ValueError, match="`image_b` is empty"):
        image_part(b"", "image_b")
    with pytest.raises(TypeError, match="binary mode"):
        image_part(io.StringIO("text"), "image_a")
    with pytest.raises(TypeError, match="`image_a` must be a path"):
        image_part([[1, 2]], "image_a")  # type: ignore[arg-type]


def test_points_and_options() -> None:
    assert points_json(np.array([[1, 2]], dtype=np.int32), "src") == [[1.0, 2.0]]
    assert points_json([], "src") == []
    with pytest.raises(ValueError, match=r"`model` must have shape \(N, 2\) or \(N, 3\), got \(4,\)"):
        points_json([1, 2, 3, 4], "model")
    assert form_fields({"dense": True, "ratio": np.float64(0.8), "max_keypoints": 500, "method": None,
                        "filter": {"beta": 0.5}}) == {"dense": "true", "ratio": "0.8", "max_keypoints": "500",
                                                      "filter": json.dumps({"beta": 0.5})}
    assert json_options({"beta": np.float32(0.5), "n_centers": np.int64(10), "tol": None}) == {"beta": 0.5,
                                                                                                 "n_centers": 10}
    with pytest.raises(ValueError, match="`beta` must be finite"):
        json_options({"beta": float("inf")})


def test_flow_files() -> None:
    flow = np.random.default_rng(0).normal(size=(4, 5, 2)).astype(np.float32)
    buffer = io.BytesIO()
    np.save(buffer, flow)
    np.testing.assert_array_equal(decode_flow(buffer.getvalue()), flow)
    flo = b"PIEH" + struct.pack("<ii", 5, 4) + flow.astype("<f4").tobytes()
    np.testing.assert_array_equal(decode_flow(flo), flow)
    assert not decode_flow(flo).flags.writeable
    with pytest.raises(ValueError, match="header says 5 x 4"):
        decode_flow(flo[:-4])
    buffer = io.BytesIO()
    np.save(buffer, flow[:, :, 0])
    with pytest.raises(ValueError, match=r"\(H, W, 2\)"):
        decode_flow(buffer.getvalue())
    with pytest.raises(ValueError, match="neither PNG nor .npy"):
        decode_image(b"\xff\xd8\xff")
