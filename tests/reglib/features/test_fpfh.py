"""FPFH descriptors and their matches: invariance under rigid motions, true matches found."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reglib.errors import InputError
from reglib.features import FPFH_BINS, fpfh, match_features, oriented_normals, voxel_downsample

SCANS = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "pointsets3d" / "scans"


def _surface_height(xy: np.ndarray) -> np.ndarray:
    return 0.3 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1]) + 0.2 * np.exp(-4 * ((xy - 0.3) ** 2).sum(1))


def _surface(n: int, rng: np.random.Generator) -> np.ndarray:
    """A bumpy height field: distinct local shapes everywhere."""
    xy = rng.uniform(-1.0, 1.0, size=(n, 2))
    return np.c_[xy, _surface_height(xy)]


def test_voxel_downsample_averages_each_cell() -> None:
    pts = np.array([[0.1, 0.1, 0.1], [0.3, 0.5, 0.1], [2.2, 0.1, 0.1], [2.4, 0.3, 0.5]])
    out = voxel_downsample(pts, 1.0)
    assert out.shape == (2, 3)
    assert np.allclose(out, [[0.2, 0.3, 0.1], [2.3, 0.2, 0.3]])
    assert voxel_downsample(np.zeros((0, 3)), 1.0).shape == (0, 3)
    assert np.allclose(voxel_downsample(np.vstack([pts, [[9.5, 9.5, 9.5]]]), 1.0, min_count=2), out)
    with pytest.raises(InputError, match="voxel"):
        voxel_downsample(pts, 0.0)


def test_drop_scatter_keeps_a_surface_and_drops_outliers_through_the_volume() -> None:
    rng = np.random.default_rng(3)
    surface = _surface(30000, rng)
    cells = voxel_downsample(surface, 0.05)
    # a clean surface keeps nearly every cube (a few sparse ones in the box's corners go), and so
    # does a curve in the plane
    clean = voxel_downsample(surface, 0.05, drop_scatter=True)
    assert len(clean) >= 0.99 * len(cells) and np.isin(clean, cells).all()
    t = rng.uniform(0.0, 6.0, size=4000)
    curve = np.c_[t, np.sin(t)]
    assert len(voxel_downsample(curve, 0.05, drop_scatter=True)) >= 0.99 * len(voxel_downsample(curve, 0.05))
    lo, hi = surface.min(0), surface.max(0)
    noisy = np.vstack([surface, rng.uniform(lo, hi, size=(30000, 3))])    # half the points outliers
    plain = voxel_downsample(noisy, 0.05)
    kept = voxel_downsample(noisy, 0.05, drop_scatter=True)
    on_surface = lambda q: np.abs(q[:, 2] - _surface_height(q[:, :2])) < 0.05   # noqa: E731
    assert on_surface(plain).mean() < 0.4                  # the outliers' cubes outnumber the surface's
    assert on_surface(kept).mean() > 0.9                   # ... and are gone
    assert on_surface(kept).sum() > 0.8 * len(cells)       # while the surface stays
    centroids, mask = voxel_downsample(noisy, 0.05, drop_scatter=True, return_mask=True)
    assert np.array_equal(centroids, kept)
    assert mask[:30000].mean() > 0.9 and mask[30000:].mean() < 0.2   # outliers in surface cubes stay


def test_drop_scatter_looks_up_counts_alike_in_a_dense_grid_and_among_the_occupied_cubes(monkeypatch) -> None:
    import importlib

    fpfh_module = importlib.import_module("reglib.features._fpfh")
    rng = np.random.default_rng(5)
    surface = _surface(20000, rng)
    noisy = np.vstack([surface, rng.uniform(surface.min(0), surface.max(0), size=(20000, 3))])
    dense = voxel_downsample(noisy, 0.05, drop_scatter=True)
    monkeypatch.setattr(fpfh_module, "_DENSE_CELLS", 0)
    assert np.array_equal(voxel_downsample(noisy, 0.05, drop_scatter=True), dense)
    assert len(dense) < 0.5 * len(voxel_downsample(noisy, 0.05))


def test_descriptors_are_invariant_and_normalised() -> None:
    rng = np.random.default_rng(0)
    pts = voxel_downsample(_surface(6000, rng), 0.04)
    rot = Rotation.random(random_state=rng).as_matrix()
    moved = pts @ rot.T + [3.0, -1.0, 2.0]
    d0 = fpfh(pts, oriented_normals(pts), 0.2)
    d1 = fpfh(moved, oriented_normals(moved), 0.2)
    assert d0.shape == (len(pts), 3 * FPFH_BINS)
    assert np.allclose(d0.reshape(-1, 3, FPFH_BINS).sum(2), 100.0)
    # the same points moved rigidly: the same histograms (a bin boundary may flip a rare pair)
    assert np.median(np.abs(d0 - d1).sum(1)) < 1e-6
    assert np.abs(d0 - d1).sum(1).max() < 5.0


def test_true_matches_found_between_two_samplings() -> None:
    rng = np.random.default_rng(1)
    surf = _surface(40000, rng)
    a = voxel_downsample(surf[:20000], 0.05)
    b = voxel_downsample(surf[20000:], 0.05)            # another sampling of the same surface
    rot = Rotation.random(random_state=rng).as_matrix()
    b_moved = b @ rot.T + [0.5, 0.2, -0.3]
    da = fpfh(a, oriented_normals(a), 0.25)
    db = fpfh(b_moved, oriented_normals(b_moved), 0.25)
    ia, ib = match_features(da, db)
    assert len(ia) > 50
    assert len(np.unique(ib)) == len(ib)                 # mutual: one-to-one
    true_dist = np.linalg.norm(a[ia] - b[ib], axis=1)
    # far more matches land near their true partner than chance (about 1 % within 2 voxels)
    assert np.mean(true_dist < 0.1) > 0.2


def test_rejects_bad_input() -> None:
    pts = np.random.default_rng(2).normal(size=(50, 3))
    with pytest.raises(InputError, match="normals"):
        fpfh(pts, pts[:10], 1.0)
    with pytest.raises(InputError, match="radius"):
        fpfh(pts, pts, -1.0)
    with pytest.raises(InputError):
        fpfh(pts[:, :2], pts[:, :2], 1.0)
    assert fpfh(np.zeros((0, 3)), np.zeros((0, 3)), 1.0).shape == (0, 33)


@pytest.mark.skipif(not (SCANS / "milk_color.npz").exists(), reason="shared scans not present")
def test_a_real_scan_is_fast() -> None:
    xyz = np.load(SCANS / "milk_color.npz")["xyz"].astype(np.float64)     # 13.7k points
    voxel = np.linalg.norm(np.ptp(xyz, 0)) / 60.0
    t0 = time.perf_counter()
    down = voxel_downsample(xyz, voxel)
    desc = fpfh(down, oriented_normals(down), 5.0 * voxel)
    assert time.perf_counter() - t0 < 2.0
    assert len(desc) == len(down) and np.isfinite(desc).all()
