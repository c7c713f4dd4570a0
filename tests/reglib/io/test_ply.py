"""PLY files read through read_point_cloud: other elements around the vertices, colour scales, bad headers named."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from reglib.errors import InputError
from reglib.io import read_point_cloud

XY = np.array([[0.5, -1.0], [2.0, 3.25], [-4.0, 0.125]])


def _ply(path, header: str, body: bytes | str = b"") -> str:
    """Write ``ply`` + header lines + ``end_header`` + body to ``path``; return the path."""
    data = f"ply\n{header}end_header\n".encode() + (body.encode() if isinstance(body, str) else body)
    path.write_bytes(data)
    return path


def test_ascii_skips_elements_before_the_vertices_and_reads_2d_points(tmp_path):
    header = ("format ascii 1.0\ncomment two elements\nobj_info scanner\n\nelement camera 2\nproperty float k\n"
              "element vertex 3\nproperty double x\nproperty double y\nproperty int flag\n")
    rows = "99\n98\n" + "".join(f"{x} {y} 7 extra\n" for x, y in XY)  # values past the properties: ignored
    cloud = read_point_cloud(_ply(tmp_path / "a.ply", header, rows))
    assert np.array_equal(cloud.points, XY) and cloud.points.dtype == np.float64
    assert cloud.colors is None and cloud.normals is None and not cloud.organized


@pytest.mark.parametrize("kind, values, scale", [
    ("float", [[0.0, 0.5, 1.0], [0.25, 0.75, 1.0], [1.0, 0.0, 0.5]], 1.0),  # floats within [0, 1]: as they are
    ("float", [[0.0, 128.0, 255.0], [64.0, 32.0, 16.0], [1.0, 2.0, 3.0]], 255.0),  # floats past 1: 8-bit values
    ("int", [[0, 128, 255], [64, 32, 16], [1, 2, 3]], 255.0),
    ("uchar", [[0, 0, 0], [0, 0, 0], [0, 0, 0]], 255.0),
])
def test_ascii_colours_are_scaled_by_their_type_and_range_and_normals_read(tmp_path, kind, values, scale):
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    header = ("format ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              f"property {kind} red\nproperty {kind} green\nproperty {kind} blue\n"
              "property float nx\nproperty float ny\nproperty float nz\n")
    xyz = np.c_[XY, [1.0, 2.0, 3.0]]
    rows = "".join(" ".join(str(v) for v in (*p, *c, *n)) + "\n" for p, c, n in zip(xyz, values, normals, strict=True))
    cloud = read_point_cloud(_ply(tmp_path / "c.ply", header, rows))
    assert np.array_equal(cloud.points, xyz)
    assert np.array_equal(cloud.colors, np.array(values, dtype=np.float64) / scale)
    assert np.array_equal(cloud.normals, normals)


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_skips_fixed_size_elements_before_the_vertices(tmp_path, order):
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    header = (f"format {fmt} 1.0\nelement camera 2\nproperty short a\nproperty double b\n"
              "element vertex 3\nproperty double x\nproperty int y\nproperty ushort z\n")
    xyz = np.array([[0.5, -1.0, 7.0], [2.25, 3.0, 0.0], [-4.0, 0.0, 65535.0]])
    body = struct.pack(order + "hdhd", 1, 2.0, 3, 4.0)
    body += b"".join(struct.pack(order + "diH", p[0], int(p[1]), int(p[2])) for p in xyz)
    cloud = read_point_cloud(_ply(tmp_path / "b.ply", header, body))
    assert np.array_equal(cloud.points, xyz) and cloud.points.dtype == np.float64


def test_binary_reads_float_colours_within_one_as_they_are(tmp_path):
    header = ("format binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
              "property float red\nproperty float green\nproperty float blue\n")
    body = struct.pack("<5f", 1.0, 2.0, 0.5, 0.25, 1.0) + struct.pack("<5f", 3.0, 4.0, 0.0, 0.75, 0.125)
    cloud = read_point_cloud(_ply(tmp_path / "f.ply", header, body))
    assert np.array_equal(cloud.points, [[1.0, 2.0], [3.0, 4.0]])
    assert np.array_equal(cloud.colors, [[0.5, 0.25, 1.0], [0.0, 0.75, 0.125]])


def test_binary_with_no_vertices_is_an_empty_set_of_points(tmp_path):
    header = "format binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
    cloud = read_point_cloud(_ply(tmp_path / "e.ply", header))
    assert cloud.points.shape == (0, 3) and cloud.points.dtype == np.float64


V2 = "element vertex 2\nproperty float x\nproperty float y\n"


@pytest.mark.parametrize("header, body, words", [
    ("format ascii 1.0\n" + V2 + "property float128 w\n", "",
     r"b.ply: unknown PLY property line 'property float128 w'"),
    ("format ascii 1.0\n" + V2 + "property float\n", "", "unknown PLY property line 'property float'"),
    ("format ascii2 1.0\n" + V2, "", r"b.ply: unknown PLY format 'ascii2'"),
    ("format\n" + V2, "", "unknown PLY format None"),
    (V2, "", "unknown PLY format None"),
    ("format ascii 1.0\nelement face 1\nproperty float x\nproperty float y\n", "",
     "b.ply: PLY header needs a vertex element with x and y properties"),
    ("format ascii 1.0\nelement vertex 2\nproperty float x\nproperty float z\n", "", "needs a vertex element with x"),
    ("format ascii 1.0\nelement vertex 2 3\nproperty float x\nproperty float y\n", "", "needs a vertex element"),
    ("format ascii 1.0\n" + V2 + "property list uchar int idx\n", "",
     "b.ply: list properties in the PLY vertex element are not supported"),
    ("format ascii 1.0\nelement vertex many\n", "", r"b.ply: bad element count 'many'"),
    ("format ascii 1.0\nelement vertex -1\n", "", r"b.ply: -1 elements; at most 50000000 are read"),
    ("format ascii 1.0\nelement face 50000001\n" + V2, "", r"b.ply: 50000001 elements; at most"),
    ("format ascii 1.0\n" + V2, "1 2\n3 x\n", "b.ply: malformed PLY vertex data: could not convert"),
    ("format ascii 1.0\n" + V2, "1 2\n3\n", "b.ply: malformed PLY vertex data"),
    ("format ascii 1.0\n" + V2, "1 2", r"b.ply: the header says 2 vertices of 2 values, the data differ"),
    ("format ascii 1.0\n" + V2, "1\n2\n", "the header says 2 vertices of 2 values, the data differ"),
    ("format binary_big_endian 1.0\nelement face 1\nproperty list uchar int idx\n" + V2, b"\x00" * 64,
     r"b.ply: element 'face' with list properties before the vertices is not supported"),
    ("format binary_little_endian 1.0\nelement camera 1\nproperty double k\n" + V2, b"\x00" * 20,
     r"b.ply: the header says 2 vertices \(16 bytes\); the file is shorter"),
    ("format ascii 1.0\n" + V2 + "property float nx\n", "", "the data differ"),  # no body at all
])
def test_bad_ply_files_are_named_input_errors(tmp_path, header, body, words):
    with pytest.raises(InputError, match=words):
        read_point_cloud(_ply(tmp_path / "b.ply", header, body))


def test_without_end_header_or_magic_it_is_not_a_ply(tmp_path):
    (tmp_path / "h.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n")
    with pytest.raises(InputError, match=r"h.ply: not a PLY file \(no 'ply' magic or no end_header\)"):
        read_point_cloud(tmp_path / "h.ply")
    (tmp_path / "m.ply").write_bytes(b"format ascii 1.0\nend_header\n")
    with pytest.raises(InputError, match="m.ply: not a PLY file"):
        read_point_cloud(tmp_path / "m.ply")
