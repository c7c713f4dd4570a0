"""Whether the data pin a rigid answer down (reglib.registration._pinned) and what ICP then says."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from reglib import register_points
from reglib._verdict import MAX_NEIGHBOUR_SUPPORT, REGISTRATION_REASONS, UNDERDETERMINED, pinned_reason
from reglib.registration._icp import ICPOptions
from reglib.registration._pinned import neighbour_support, tight_polish
from reglib.registration._rigid import RigidFit

IDENTITY = np.c_[np.eye(3), np.zeros(3)]


def _bumpy(n: int, rng: np.random.Generator) -> np.ndarray:
    """An asymmetric bumpy height field (extent about 3): every motion changes its fit."""
    xy = rng.uniform(-1.0, 1.0, size=(n, 2)) * [1.5, 1.0]
    z = 0.3 * np.sin(2.0 * xy[:, 0]) * np.cos(3.0 * xy[:, 1]) + 0.25 * xy[:, 0] ** 2 + 0.1 * xy[:, 1]
    return np.c_[xy, z]


def _trough(n: int, rng: np.random.Generator) -> np.ndarray:
    """A long parabolic trough along y (extent about 4): a shift along y leaves it on itself."""
    xy = rng.uniform(-1.0, 1.0, size=(n, 2)) * [0.6, 2.0]
    return np.c_[xy, 0.4 * xy[:, 0] ** 2]


def test_a_bumpy_surface_pins_the_true_pose() -> None:
    rng = np.random.default_rng(0)
    target = _bumpy(6000, rng)
    model = _bumpy(3000, rng)
    ratio = neighbour_support(model, cKDTree(target), IDENTITY)
    assert 0.0 < ratio < MAX_NEIGHBOUR_SUPPORT
    assert pinned_reason(ratio) is None


def test_a_trough_does_not_pin_a_shift_along_it() -> None:
    rng = np.random.default_rng(0)
    target = _trough(6000, rng)
    model = _trough(3000, rng)
    model = model[np.abs(model[:, 1]) < 1.0]  # the middle: a shift along y keeps it on the target
    ratio = neighbour_support(model, cKDTree(target), IDENTITY)
    assert ratio >= MAX_NEIGHBOUR_SUPPORT
    assert pinned_reason(ratio) == UNDERDETERMINED


def test_an_answer_slid_off_its_best_pose_has_a_better_supported_neighbour() -> None:
    rng = np.random.default_rng(1)
    target = _bumpy(6000, rng)
    model = _bumpy(3000, rng)
    slid = IDENTITY.copy()
    slid[:, 3] = [0.08, -0.05, 0.0]  # about 3 % of the extent off
    assert neighbour_support(model, cKDTree(target), slid) >= MAX_NEIGHBOUR_SUPPORT


def test_nothing_overlapping_is_no_evidence() -> None:
    rng = np.random.default_rng(2)
    target = _bumpy(500, rng)
    far = np.c_[np.eye(3), [100.0, 0.0, 0.0]]
    assert neighbour_support(_bumpy(500, rng), cKDTree(target), far) == 0.0


def _pair(surface, overlap_cut: float, seed: int):
    """Two parts of one surface split along y that share the band |y| < overlap_cut, the model re-posed."""
    rng = np.random.default_rng(seed)
    pts = surface(12000, rng)
    pts = pts + rng.normal(scale=0.003, size=pts.shape)
    rot = Rotation.from_rotvec([0.4, -0.9, 0.3]).as_matrix()
    shift = np.array([0.5, -0.2, 0.3])
    model = (pts[pts[:, 1] < overlap_cut] - shift) @ rot      # target = rot @ model + shift
    target = pts[pts[:, 1] > -overlap_cut]
    return model, target, rot


def test_icp_on_a_trough_at_low_overlap_is_not_converged() -> None:
    # the pose along the trough is not fixed by the data: whatever the ICP answers is not to be used
    model, target, _ = _pair(_trough, 0.5, 3)
    res = register_points(model, target, method="icp", rng=0)
    assert not res.converged
    assert res.reason in REGISTRATION_REASONS


def test_a_settled_answer_slid_along_a_trough_is_underdetermined(monkeypatch: pytest.MonkeyPatch) -> None:
    # the robust ICP is made to settle on the true rotation slid along the trough (as it does on real scans
    # where the overlap lets it): the overlap figures look like a success's, the neighbours say it is not one
    import reglib.registration._icp as icp_module
    model, target, rot = _pair(_trough, 0.5, 3)
    slid = np.c_[rot, np.array([0.5, -0.2, 0.3]) + [0.0, 0.15, 0.0]]
    monkeypatch.setattr(icp_module, "refine_icp",
                        lambda *args, **kw: RigidFit(matrix=slid, n_iter=10, converged=True, reach=0.01))
    fit = icp_module.icp_register(model, target, ICPOptions(), np.random.default_rng(0))
    assert not fit.converged and fit.reason == UNDERDETERMINED
    np.testing.assert_array_equal(fit.matrix, slid)  # the answer itself is still given
    unchecked = icp_module.icp_register(model, target, ICPOptions(verify=False), np.random.default_rng(0))
    assert unchecked.converged and unchecked.reason is None


def test_icp_on_a_bumpy_surface_at_the_same_overlap_stays_converged() -> None:
    model, target, rot = _pair(_bumpy, 0.3, 3)
    res = register_points(model, target, method="icp", rng=0)
    matrix = np.asarray(res.transform.linear.matrix)
    assert np.degrees(Rotation.from_matrix(matrix[:, :3] @ rot.T).magnitude()) < 1.0
    assert res.converged and res.reason is None


def test_a_slid_answer_at_high_overlap_is_underdetermined_too(monkeypatch: pytest.MonkeyPatch) -> None:
    # a slide can raise the measured overlap over the reverse run's 65 % gate (a scan cut in two, slid over
    # itself); the neighbours are asked at any overlap (the search start: no feature inliers to say it first)
    import reglib.registration._icp as icp_module
    from reglib.registration._support import measure_support, median_spacing
    model, target, rot = _pair(_trough, 1.5, 3)
    slid = np.c_[rot, np.array([0.5, -0.2, 0.3]) + [0.0, 0.15, 0.0]]
    tree = cKDTree(target)
    support = measure_support(model, tree, median_spacing(tree), slid, np.random.default_rng(0))
    assert support.overlap >= icp_module._VERIFY_BELOW  # the case the gate used to let through
    monkeypatch.setattr(icp_module, "refine_icp",
                        lambda *args, **kw: RigidFit(matrix=slid, n_iter=10, converged=True, reach=0.01))
    fit = icp_module.icp_register(model, target, ICPOptions(init="search"), np.random.default_rng(0))
    assert not fit.converged and fit.reason == UNDERDETERMINED


def _pose_error(matrix: np.ndarray, points: np.ndarray) -> float:
    """Mean distance the pose moves ``points`` away from where the identity leaves them."""
    return float(np.linalg.norm(points @ matrix[:, :3].T + matrix[:, 3] - points, axis=1).mean())


def test_the_tight_polish_brings_a_slid_answer_back() -> None:
    rng = np.random.default_rng(3)
    target = _bumpy(6000, rng)
    model = _bumpy(4000, rng)
    model = model[model[:, 0] < 0.0]  # a part of the surface: the target is the whole
    turn = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(1.0)]).as_matrix()
    slid = np.c_[turn, [0.04, -0.03, 0.01]]  # a few target spacings and a degree off
    tree = cKDTree(target)
    polished, settled = tight_polish(model, tree, slid)
    assert settled
    assert _pose_error(slid, model) > 0.04
    assert _pose_error(polished, model) < 0.1 * _pose_error(slid, model)


def test_the_tight_polish_keeps_a_right_answer() -> None:
    rng = np.random.default_rng(4)
    target = _bumpy(6000, rng)
    model = _bumpy(3000, rng)
    kept, settled = tight_polish(model, cKDTree(target), IDENTITY)
    assert kept is IDENTITY and not settled


def test_the_tight_polish_keeps_a_pose_with_nothing_in_reach() -> None:
    rng = np.random.default_rng(5)
    target = _bumpy(3000, rng)
    far = IDENTITY.copy()
    far[:, 3] = [50.0, 0.0, 0.0]
    kept, settled = tight_polish(_bumpy(1000, rng), cKDTree(target), far)
    assert kept is far and not settled
