"""PCD files read through read_point_cloud: ascii and binary fields, packed colours, organized grids, bad headers."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from reglib.errors import InputError
from reglib.io import read_point_cloud

XYZ = np.array([[0.5, -1.0, 2.0], [2.25, 3.0, -0.5], [-4.0, 0.125, 1.0], [1.5, 1.5, 1.5]])
NORMALS = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.6, 0.8, 0.0]])
RGB = np.array([[255, 128, 64], [0, 0, 0], [1, 2, 3], [10, 200, 30]])
PACKED = (RGB[:, 0] << 16) | (RGB[:, 1] << 8) | RGB[:, 2]


def _pcd(path, header: str, body: bytes | str) -> str:
    path.write_bytes(header.encode() + (body.encode() if isinstance(body, str) else body))
    return path


def test_ascii_float_packed_rgb_normals_and_wide_fields_on_an_organized_grid(tmp_path):
    header = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z hist normal_x normal_y normal_z rgb\n"
              "SIZE 4 4 4 4 4 4 4 4\nTYPE F F F F F F F F\nCOUNT 1 1 1 2 1 1 1 1\nWIDTH 2\nHEIGHT 2\n"
              "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA ascii\n")
    as_float = PACKED.astype(np.uint32).view(np.float32)  # the colour's bits read as a float32, as PCL writes it
    rows = "".join(" ".join(repr(float(v)) for v in (*p, 9.0, 8.0, *n, f)) + "\n"
                   for p, n, f in zip(XYZ, NORMALS, as_float, strict=True))
    cloud = read_point_cloud(_pcd(tmp_path / "a.pcd", header, rows))
    assert cloud.organized and cloud.points.shape == (2, 2, 3)
    assert np.array_equal(cloud.points.reshape(-1, 3), XYZ)
    assert np.array_equal(cloud.normals, NORMALS.reshape(2, 2, 3))
    assert np.array_equal(cloud.colors, RGB.reshape(2, 2, 3) / 255.0)


def test_ascii_unsigned_rgb_lower_case_keys_and_default_count_and_height(tmp_path):
    header = "fields x y z rgb\nsize 4 4 4 4\ntype f f f u\nwidth 4\ndata ASCII\n"
    rows = "".join(f"{p[0]} {p[1]} {p[2]} {c}\n" for p, c in zip(XYZ, PACKED, strict=True))
    cloud = read_point_cloud(_pcd(tmp_path / "u.pcd", header, rows))
    assert np.array_equal(cloud.points, XYZ) and not cloud.organized
    assert np.array_equal(cloud.colors, RGB / 255.0) and cloud.normals is None


def test_binary_skips_wide_fields_and_reads_rgba_normals_and_mixed_types(tmp_path):
    header = ("VERSION 0.7\nFIELDS x y z hist normal_x normal_y normal_z rgba\nSIZE 8 4 2 4 4 4 4 4\n"
              "TYPE F F I F F F F U\nCOUNT 1 1 1 3 1 1 1 1\nWIDTH 4\nHEIGHT 1\nPOINTS 4\nDATA binary\n")
    pts = np.c_[XYZ[:, :2], [7, -3, 0, 32767]]
    body = b"".join(struct.pack("<dfh3f3fI", p[0], p[1], int(p[2]), 1.0, 2.0, 3.0, *n, (255 << 24) | int(c))
                    for p, n, c in zip(pts, NORMALS.astype(np.float32), PACKED, strict=True))
    cloud = read_point_cloud(_pcd(tmp_path / "b.pcd", header, body))
    assert np.array_equal(cloud.points, pts) and cloud.points.dtype == np.float64
    assert np.array_equal(cloud.normals, NORMALS.astype(np.float32).astype(np.float64))
    assert np.array_equal(cloud.colors, RGB / 255.0)


def test_binary_organized_normals_keep_the_grid_and_2d_points_do_not(tmp_path):
    header = ("FIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\nTYPE F F F F F F\nCOUNT 1 1 1 1 1 1\n"
              "WIDTH 2\nHEIGHT 2\nDATA binary\n")
    body = b"".join(struct.pack("<6f", *p, *n) for p, n in zip(XYZ, NORMALS, strict=True))
    cloud = read_point_cloud(_pcd(tmp_path / "o.pcd", header, body))
    assert cloud.points.shape == cloud.normals.shape == (2, 2, 3) and cloud.colors is None
    assert np.array_equal(cloud.normals.reshape(-1, 3), NORMALS.astype(np.float32))
    flat = "FIELDS x y\nSIZE 4 4\nTYPE F F\nWIDTH 2\nHEIGHT 2\nDATA binary\n"
    cloud = read_point_cloud(_pcd(tmp_path / "f.pcd", flat, XYZ[:, :2].astype("<f4").tobytes()))
    assert cloud.points.shape == (4, 2) and not cloud.organized
    assert np.array_equal(cloud.points, XYZ[:, :2])


HEAD = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"


@pytest.mark.parametrize("header, body, words", [
    ("VERSION 0.7\n" + HEAD + "WIDTH 2\n", "", r"c.pcd: not a PCD file \(no DATA line\)"),
    ("FIELDS x y z\nTYPE F F F\nWIDTH 2\nDATA ascii\n", "", r"c.pcd: malformed PCD header \('SIZE'\)"),
    ("FIELDS x y z\nSIZE 4 4 four\nTYPE F F F\nWIDTH 2\nDATA ascii\n", "", r"malformed PCD header \(invalid literal"),
    (HEAD + "WIDTH abc\nDATA ascii\n", "", r"c.pcd: malformed PCD header \(c.pcd: bad element count 'abc'\)"),
    (HEAD + "WIDTH 2\nHEIGHT -2\nDATA ascii\n", "", r"malformed PCD header \(c.pcd: -2 elements; at most"),
    (HEAD + "WIDTH\nDATA ascii\n", "", r"malformed PCD header \(list index out of range\)"),
    (HEAD + "WIDTH 2\nDATA\n", "", r"malformed PCD header \(list index out of range\)"),
    ("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1\nWIDTH 2\nDATA ascii\n", "",
     "c.pcd: PCD header needs FIELDS with x and y and matching SIZE / TYPE / COUNT"),
    ("FIELDS x z\nSIZE 4 4\nTYPE F F\nWIDTH 2\nDATA ascii\n", "", "PCD header needs FIELDS with x and y"),
    (HEAD + "WIDTH 50000\nHEIGHT 50000\nDATA ascii\n", "", r"c.pcd: 2500000000 points; at most 50000000 are read"),
    ("FIELDS x y z\nSIZE 4 4 4\nTYPE F F Q\nWIDTH 2\nDATA ascii\n", "",
     r"c.pcd: unknown PCD TYPE in \['F', 'F', 'Q'\]"),
    (HEAD + "WIDTH 2\nDATA ascii\n", "1 2 3\n4 5\n", "c.pcd: the header says 2 points of 3 values; the data are short"),
    (HEAD + "WIDTH 2\nDATA binary\n", b"\x00" * 23, r"c.pcd: the header says 2 points \(24 bytes\); the file is short"),
    (HEAD + "WIDTH 2\nDATA weird\n", "", r"c.pcd: PCD DATA 'weird' is not supported \(ascii and binary are\)"),
    (HEAD + "WIDTH 2\nDATA Binary_Compressed\n", b"\x00" * 40, r"PCD DATA 'binary_compressed' is not supported"),
])
def test_bad_pcd_files_are_named_input_errors(tmp_path, header, body, words):
    with pytest.raises(InputError, match=words):
        read_point_cloud(_pcd(tmp_path / "c.pcd", header, body))
