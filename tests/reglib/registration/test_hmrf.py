"""HMRF-ICP on organized scans: the mean field, options, and low-overlap recovery of known motions."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reglib.errors import InputError
from reglib.registration._hmrf import HMRFOptions, icp_hmrf_register, mean_field
from reglib.registration._icp import ICPOptions, icp_register


def _scan(rows: int = 60, cols: int = 90) -> np.ndarray:
    """An organized depth-camera-like scan (rows, cols, 3) of a bumpy scene, NaN in a hole."""
    u, v = np.meshgrid(np.linspace(-1.2, 1.2, cols), np.linspace(-0.8, 0.8, rows))
    z = 2.0 + 0.25 * np.sin(3.0 * u) * np.cos(2.0 * v) + 0.15 * u * v + 0.1 * u
    grid = np.dstack([u * z / 2.0, v * z / 2.0, z])
    grid[20:26, 40:47] = np.nan                                        # nothing seen there
    return grid


def _rotation(axis, degrees):
    """Rotation by ``degrees`` about ``axis`` (scipy's, independent of the library)."""
    return Rotation.from_rotvec(np.deg2rad(degrees) * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix()


def _angle_error(matrix: np.ndarray, rot: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(matrix[:, :3] @ rot.T).magnitude()))


def _low_overlap_pair(overlap: float, rng: np.random.Generator, degrees: float = 6.0):  # type: ignore[no-untyped-def]
    """Model = left columns of the scan (moved), target = right columns: ``overlap`` of the model shared."""
    scan = _scan()
    cols = scan.shape[1]
    wm = round(cols / (2.0 - overlap))
    model_grid = scan[:, :wm].copy()
    target = scan[:, cols - wm:] + rng.normal(scale=0.002, size=scan[:, cols - wm:].shape)
    rot, shift = _rotation([0.2, 1.0, 0.3], degrees), np.array([0.03, -0.02, 0.04])
    moved = (model_grid - shift) @ rot                                 # truth: target = rot @ model + shift
    return moved, target, rot, shift


def test_mean_field_smooths_isolated_labels_and_reduces_to_the_likelihood() -> None:
    ev = np.full((8, 8), 1.0)
    ev[3, 3] = -1.5                                                   # a lone weak outlier vote
    seen = np.ones((8, 8), dtype=bool)
    independent = mean_field(ev, seen, beta=0.0, sweeps=3)
    np.testing.assert_allclose(independent, np.tanh(ev / 2.0))
    coupled = mean_field(ev, seen, beta=1.0, sweeps=10)
    assert independent[3, 3] < 0 < coupled[3, 3]
    seen[0, 0] = False
    assert mean_field(ev, seen, beta=1.0, sweeps=3)[0, 0] == 0.0      # no data: no opinion


def test_options_reject_bad_values() -> None:
    with pytest.raises(InputError, match=r"`beta` must be <= 10"):
        HMRFOptions(beta=20.0)
    with pytest.raises(InputError, match=r"`mf_sweeps` must be a positive integer"):
        HMRFOptions(mf_sweeps=0)
    with pytest.raises(InputError, match=r"`variant` must be one of"):
        HMRFOptions(variant="plane")  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"`hard` must be a bool"):
        HMRFOptions(hard=1)  # type: ignore[arg-type]
    assert isinstance(HMRFOptions().icp_options(), ICPOptions)


def test_options_share_the_loop_fields_and_the_renamed_tol() -> None:
    opts = HMRFOptions(tol=1e-6, variant="point_to_point")
    icp = opts.icp_options()
    assert (icp.tol, icp.variant) == (1e-6, "point_to_point")
    with pytest.raises(InputError, match=r"`tolerance` was renamed to `tol`"):
        HMRFOptions(tolerance=1e-6)  # type: ignore[call-arg]
    with pytest.raises(InputError, match=r"`max_points` must be an integer >= 100"):
        HMRFOptions(max_points=10)


def test_recovers_motion_at_low_overlap() -> None:
    moved, target, rot, shift = _low_overlap_pair(0.4, np.random.default_rng(0))
    fit = icp_hmrf_register(moved, target, HMRFOptions(), np.random.default_rng(0))
    assert fit.matrix.shape == (3, 4)
    assert _angle_error(fit.matrix, rot) < 0.3
    np.testing.assert_allclose(fit.matrix[:, 3], shift, atol=0.01)
    assert fit.converged and fit.reach > 0


def test_point_to_point_variant() -> None:
    moved, target, rot, shift = _low_overlap_pair(0.9, np.random.default_rng(0), degrees=3.0)
    fit = icp_hmrf_register(moved, target, HMRFOptions(variant="point_to_point", init="given", max_iter=200),
                            np.random.default_rng(0))
    assert _angle_error(fit.matrix, rot) < 0.5
    np.testing.assert_allclose(fit.matrix[:, 3], shift, atol=0.02)


def test_beats_fixed_trimming_at_low_overlap() -> None:
    moved, target, rot, _ = _low_overlap_pair(0.35, np.random.default_rng(1))
    flat = moved.reshape(-1, 3)
    flat = flat[np.isfinite(flat).all(1)]
    tflat = target.reshape(-1, 3)
    trimmed = icp_register(flat, tflat[np.isfinite(tflat).all(1)],
                           ICPOptions(loss="trimmed", trim_ratio=0.7, init="given"), np.random.default_rng(0))
    hmrf = icp_hmrf_register(moved, target, HMRFOptions(init="given"), np.random.default_rng(0))
    assert _angle_error(hmrf.matrix, rot) < 0.3
    assert _angle_error(trimmed.matrix, rot) > 2.0 * _angle_error(hmrf.matrix, rot)


def test_organized_target_with_nan_and_a_large_rotation() -> None:
    moved, target, rot, _ = _low_overlap_pair(0.7, np.random.default_rng(2), degrees=50.0)
    target = target.copy()
    target[:5] = np.nan
    fit = icp_hmrf_register(moved, target, HMRFOptions(), np.random.default_rng(0))
    assert _angle_error(fit.matrix, rot) < 0.5


def test_stride_keeps_large_grids_bounded_and_deterministic() -> None:
    moved, target, rot, _ = _low_overlap_pair(0.6, np.random.default_rng(3))
    opts = HMRFOptions(max_points=1200, init="given")
    a = icp_hmrf_register(moved, target, opts, np.random.default_rng(5))
    b = icp_hmrf_register(moved, target, opts, np.random.default_rng(5))
    np.testing.assert_array_equal(a.matrix, b.matrix)
    assert _angle_error(a.matrix, rot) < 0.5


def test_errors() -> None:
    rng = np.random.default_rng(4)
    with pytest.raises(InputError, match=r"`model` must be an organized scan of shape \(H, W, 3\)"):
        icp_hmrf_register(rng.normal(size=(100, 3)), rng.normal(size=(100, 3)), HMRFOptions(), rng)
    grid = _scan(10, 10)
    with pytest.raises(InputError, match=r"`target_normals` must have shape"):
        icp_hmrf_register(grid, grid.reshape(-1, 3), HMRFOptions(), rng, target_normals=np.ones((3, 3)))
    empty = np.full((10, 10, 3), np.nan)
    empty[0, 0] = 1.0
    with pytest.raises(InputError, match=r"at least 3 seen points"):
        icp_hmrf_register(empty, grid.reshape(-1, 3), HMRFOptions(), rng)
