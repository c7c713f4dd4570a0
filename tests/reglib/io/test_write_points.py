"""Writing point sets as users hold them: uint8 or [0, 1] colours and normals kept in PLY and PCD, bad colours named."""
from __future__ import annotations

import numpy as np
import pytest

from reglib.errors import InputError
from reglib.io import PointCloud, read_point_cloud, write_point_cloud, write_points

RNG = np.random.default_rng(7)
PTS = RNG.normal(size=(40, 3))
RGB8 = RNG.integers(0, 256, (40, 3)).astype(np.uint8)
RGB8[0], RGB8[1] = 255, 0  # the ends of the range: 0 and 255 were once both written as 255
NORMALS = RNG.normal(size=(40, 3))
NORMALS /= np.linalg.norm(NORMALS, axis=1, keepdims=True)


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_uint8_colours_and_normals_read_back_exactly(tmp_path, suffix):
    write_points(tmp_path / f"c{suffix}", PTS, colors=RGB8, normals=NORMALS)
    cloud = read_point_cloud(tmp_path / f"c{suffix}")
    assert np.array_equal(cloud.points, PTS)
    assert np.array_equal(cloud.normals, NORMALS)
    assert np.array_equal(np.round(cloud.colors * 255).astype(np.uint8), RGB8)
    assert np.array_equal(cloud.colors, RGB8 / 255.0)


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_float_colours_are_written_as_the_nearest_8_bit_level(tmp_path, suffix):
    rgb = np.array([[0.0, 0.5, 1.0], [0.2, 0.9, 0.001]])
    write_points(tmp_path / f"f{suffix}", PTS[:2], colors=rgb)
    back = read_point_cloud(tmp_path / f"f{suffix}").colors
    assert np.array_equal(back * 255, [[0, 128, 255], [51, 230, 0]])


def test_two_dimensional_points_and_normals_get_a_zero_z(tmp_path):
    n2 = NORMALS[:5, :2]
    write_points(tmp_path / "p.ply", PTS[:5, :2], normals=n2)
    cloud = read_point_cloud(tmp_path / "p.ply")
    assert np.array_equal(cloud.points, np.c_[PTS[:5, :2], np.zeros(5)])
    assert np.array_equal(cloud.normals, np.c_[n2, np.zeros(5)]) and cloud.colors is None


@pytest.mark.parametrize("colors, words", [
    (RGB8.astype(np.int64), r"int64 values in \[0, 255\]"),  # 8-bit values in a wider type: not guessed at
    (RGB8 / 100.0, r"float64 values in \[0, 2.55\]"),
    (RGB8 / 255.0 - 1.0, r"float64 values in \[-1, 0\]"),
    (RGB8 > 100, "got dtype bool"),
    (np.full((40, 3), np.nan), "must be finite"),
])
def test_colours_that_are_neither_uint8_nor_in_0_1_are_refused_by_dtype_and_range(tmp_path, colors, words):
    with pytest.raises(InputError, match=r"`colors` must be RGB values in \[0, 1\] .*" + words
                       if "finite" not in words else words):
        write_points(tmp_path / "x.ply", PTS, colors=colors)
    assert not (tmp_path / "x.ply").exists()


def test_shapes_and_formats_without_fields_are_named(tmp_path):
    with pytest.raises(InputError, match=r"`colors` must have shape \(40, 3\), got \(39, 3\)"):
        write_points(tmp_path / "x.pcd", PTS, colors=RGB8[:-1])
    with pytest.raises(InputError, match=r"`normals` must have the shape of the points, \(40, 3\)"):
        write_points(tmp_path / "x.pcd", PTS, normals=NORMALS[:, :2])
    with pytest.raises(InputError, match="`normals` must be finite"):
        write_points(tmp_path / "x.pcd", PTS, normals=NORMALS * np.inf)
    for name in ("x.txt", "x.npy"):
        with pytest.raises(InputError, match=rf"{name}: a .* file holds the points alone; `colors` go into .ply"):
            write_points(tmp_path / name, PTS, colors=RGB8)


def test_a_cloud_is_written_with_what_the_format_holds(tmp_path):
    cloud = PointCloud(points=PTS, colors=RGB8 / 255.0, normals=NORMALS)
    write_point_cloud(tmp_path / "c.pcd", cloud)
    back = read_point_cloud(tmp_path / "c.pcd")
    assert np.array_equal(back.points, PTS) and np.array_equal(back.colors, cloud.colors)
    assert np.array_equal(back.normals, NORMALS)
    write_point_cloud(tmp_path / "c.npy", cloud)  # .npy holds the points alone
    assert np.array_equal(read_point_cloud(tmp_path / "c.npy").points, PTS)


def test_an_organized_cloud_is_written_as_the_points_that_were_seen(tmp_path):
    grid = PTS[:12].reshape(3, 4, 3).copy()
    grid[1, 2] = np.nan
    colors = (RGB8[:12] / 255.0).reshape(3, 4, 3)
    write_point_cloud(tmp_path / "o.ply", PointCloud(points=grid, colors=colors))
    back = read_point_cloud(tmp_path / "o.ply")
    seen = np.ones(12, dtype=bool)
    seen[6] = False
    assert np.array_equal(back.points, PTS[:12][seen])
    assert np.array_equal(back.colors, colors.reshape(-1, 3)[seen])
