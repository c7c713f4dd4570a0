"""Point-set files: text, .npy, PLY and PCD (ASCII and binary) read back exactly, bad files named."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from reglib.errors import InputError
from reglib.io import read_matches, read_point_cloud, read_points, write_points

PTS = np.random.default_rng(0).normal(size=(25, 3))
RGB = np.random.default_rng(1).integers(0, 256, (25, 3))


@pytest.mark.parametrize("suffix", [".txt", ".xyz", ".npy", ".ply", ".pcd"])
def test_write_then_read_is_exact(tmp_path, suffix):
    write_points(tmp_path / f"p{suffix}", PTS)
    assert np.array_equal(read_points(tmp_path / f"p{suffix}"), PTS)


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_colours_round_trip_in_ply_and_pcd(tmp_path, suffix):
    write_points(tmp_path / f"p{suffix}", PTS, colors=RGB / 255.0)
    cloud = read_point_cloud(tmp_path / f"p{suffix}")
    assert np.array_equal(cloud.points, PTS)
    assert np.allclose(cloud.colors * 255.0, RGB)


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_ply_with_colours_normals_and_faces(tmp_path, order):
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    header = (f"ply\nformat {fmt} 1.0\ncomment made by a test\nelement vertex {len(PTS)}\n"
              "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
              "property float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n").encode()
    normals = PTS / np.linalg.norm(PTS, axis=1, keepdims=True)
    rows = b"".join(struct.pack(order + "6f3B", *p, *n, *c) for p, n, c in zip(PTS, normals, RGB, strict=True))
    face = struct.pack(order + "B3i", 3, 0, 1, 2)
    (tmp_path / "b.ply").write_bytes(header + rows + face)
    cloud = read_point_cloud(tmp_path / "b.ply")
    np.testing.assert_allclose(cloud.points, PTS.astype(np.float32), rtol=0)
    np.testing.assert_allclose(cloud.normals, normals.astype(np.float32), rtol=0)
    assert np.allclose(cloud.colors * 255, RGB)


def test_binary_organized_pcd_keeps_the_grid_and_its_holes(tmp_path):
    h, w = 4, 5
    xyz = np.random.default_rng(2).normal(size=(h, w, 3)).astype(np.float32)
    xyz[1, 2] = np.nan
    packed = ((RGB[:h * w, 0] << 16) | (RGB[:h * w, 1] << 8) | RGB[:h * w, 2]).astype(np.uint32)
    header = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
              f"WIDTH {w}\nHEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {h * w}\nDATA binary\n").encode()
    pairs = zip(xyz.reshape(-1, 3), packed, strict=True)
    body = b"".join(struct.pack("<3f", *p) + struct.pack("<I", c) for p, c in pairs)
    (tmp_path / "o.pcd").write_bytes(header + body)
    cloud = read_point_cloud(tmp_path / "o.pcd")
    assert cloud.organized and cloud.points.shape == (h, w, 3)
    assert np.isnan(cloud.points[1, 2]).all() and np.array_equal(cloud.points[0], xyz[0].astype(np.float64))
    assert np.allclose(cloud.colors.reshape(-1, 3) * 255, RGB[:h * w])


@pytest.mark.parametrize("name, content, words", [
    ("t.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nproperty float y\n"
              b"end_header\n" + b"\x00" * 12, "shorter"),
    ("c.pcd", b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n"
              b"DATA binary_compressed\n", "binary_compressed"),
    ("n.ply", b"not a ply", "not a PLY"),
    ("x.obj", b"v 1 2 3", "unknown point file suffix"),
    ("bad.txt", b"1 2 three\n", "not a numeric table"),
])
def test_bad_files_are_named_input_errors(tmp_path, name, content, words):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(InputError, match=words):
        read_points(tmp_path / name)


def test_missing_file_and_matches(tmp_path):
    with pytest.raises(InputError, match="no such point file"):
        read_points(tmp_path / "none.ply")
    np.savetxt(tmp_path / "m.txt", np.c_[PTS[:, :2], PTS[:, :2] + 1])
    src, dst = read_matches(tmp_path / "m.txt")
    assert np.allclose(dst - src, 1.0)
    np.savetxt(tmp_path / "m5.txt", np.zeros((3, 5)))
    with pytest.raises(InputError, match="4 .2-D. or 6"):
        read_matches(tmp_path / "m5.txt")


@pytest.mark.parametrize("content", [b"", b"# a comment, no numbers\n", b"\n\n"])
def test_a_text_file_without_rows_is_a_named_input_error_and_no_warning(tmp_path, content):
    import warnings

    (tmp_path / "e.txt").write_bytes(content)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's "input contained no data" used to reach the user's terminal
        with pytest.raises(InputError, match="e.txt: no rows of numbers"):
            read_points(tmp_path / "e.txt")
        with pytest.raises(InputError, match="e.txt: no rows of numbers"):
            read_matches(tmp_path / "e.txt")


@pytest.mark.parametrize("name, text", [
    ("m.csv", "x_a,y_a,x_b,y_b\n1,2,3,4\n5,6,7,8\n"),
    ("m.txt", "# matches of a to b\n\nx_a y_a x_b y_b\n1 2 3 4\n5 6 7 8\n"),
    ("m.csv", "1,2,3,4\n5,6,7,8\n"),
])
def test_a_first_row_of_non_numbers_is_a_header(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    src, dst = read_matches(tmp_path / name)
    assert np.array_equal(src, [[1, 2], [5, 6]]) and np.array_equal(dst, [[3, 4], [7, 8]])


def test_header_rule_reads_point_tables_and_keeps_other_words_errors(tmp_path):
    (tmp_path / "p.csv").write_text("x,y,z\n1,2,3\n")
    assert np.array_equal(read_points(tmp_path / "p.csv"), [[1, 2, 3]])
    (tmp_path / "mixed.csv").write_text("x,2,3,4\n1,2,3,4\n")  # not all non-numbers: not a header
    with pytest.raises(InputError, match="mixed.csv: not a numeric table"):
        read_matches(tmp_path / "mixed.csv")
    (tmp_path / "late.csv").write_text("1,2,3,4\nx_a,y_a,x_b,y_b\n")  # only the first row may be one
    with pytest.raises(InputError, match="not a numeric table"):
        read_matches(tmp_path / "late.csv")
    (tmp_path / "only.csv").write_text("x_a,y_a,x_b,y_b\n")
    with pytest.raises(InputError, match=r"only.csv: no rows of numbers in the file \(only a header\)"):
        read_matches(tmp_path / "only.csv")


def test_an_npz_with_other_arrays_says_which_it_needs_and_which_it_has(tmp_path):
    np.savez(tmp_path / "m.npz", a=np.zeros((3, 2)), points=np.zeros((3, 2)))
    with pytest.raises(InputError, match=r"needs arrays `src` and `dst`.*it holds \['a', 'points'\]"):
        read_matches(tmp_path / "m.npz")
    (tmp_path / "broken.npz").write_bytes(b"PK not really a zip")
    with pytest.raises(InputError, match="broken.npz: not a readable .npz file"):
        read_matches(tmp_path / "broken.npz")
    np.savez(tmp_path / "ok.npz", src=np.ones((3, 2)), dst=np.zeros((3, 2)))
    src, dst = read_matches(tmp_path / "ok.npz")
    assert src.shape == dst.shape == (3, 2) and src.sum() == 6
