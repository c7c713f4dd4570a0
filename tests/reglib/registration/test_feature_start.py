"""The feature start of rigid ICP (init="features"), RANSAC on matches, and failures said."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import reglib
from reglib._verdict import REGISTRATION_REASONS
from reglib.registration._feature_start import feature_start, ransac_rigid
from reglib.registration._hmrf import HMRFOptions
from reglib.registration._icp_options import ICPOptions
from reglib.registration._result import Registration
from reglib.registration._support import Support, support_reason

SCANS = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "pointsets3d" / "scans"


def _angle(r: np.ndarray) -> float:
    return float(np.rad2deg(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def _milk() -> np.ndarray:
    if not (SCANS / "milk_color.npz").exists():
        pytest.skip("shared scans not present")
    return np.load(SCANS / "milk_color.npz")["xyz"].astype(np.float64)


def test_defaults() -> None:
    assert ICPOptions().init == "features"
    assert HMRFOptions().init == "search"           # unchanged for the other methods
    assert ICPOptions(init="given").init == "given"


def test_ransac_recovers_the_motion_from_mostly_wrong_matches() -> None:
    rng = np.random.default_rng(0)
    src = rng.uniform(-1, 1, size=(300, 3))
    rot, t = Rotation.random(random_state=rng).as_matrix(), np.array([0.3, -2.0, 1.0])
    dst = src @ rot.T + t + rng.normal(scale=0.005, size=src.shape)
    wrong = rng.random(300) < 0.7                     # 70 % of the matches are wrong
    dst[wrong] = rng.uniform(-3, 3, size=(int(wrong.sum()), 3))
    hyps = ransac_rigid(src, dst, 0.03, 5000, np.random.default_rng(1))
    m, n_in = hyps[0]
    assert _angle(m[:, :3] @ rot.T) < 0.5
    assert np.linalg.norm(m[:, 3] - t) < 0.02
    assert abs(n_in - int((~wrong).sum())) <= 5
    assert ransac_rigid(src[:2], dst[:2], 0.03, 100, rng) == []


def test_feature_start_is_seeded() -> None:
    pts = _milk()[::3]
    rng = np.random.default_rng(3)
    moved = pts @ Rotation.random(random_state=rng).as_matrix().T
    a = feature_start(moved, pts, ICPOptions(), np.random.default_rng(7))
    b = feature_start(moved, pts, ICPOptions(), np.random.default_rng(7))
    assert a[0] is not None and b[0] is not None
    assert np.array_equal(a[0].matrix, b[0].matrix)
    assert feature_start(moved[:, :2], pts[:, :2], ICPOptions(), np.random.default_rng(7)) == (None, None)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_any_rotation_of_a_partial_scan(seed: int) -> None:
    pts = _milk()
    rng = np.random.default_rng(seed)
    u = rng.normal(size=3)
    proj = pts @ (u / np.linalg.norm(u))
    lo, hi = np.quantile(proj, [0.3, 0.7])
    model, target = pts[proj <= hi], pts[proj >= lo]  # overlap: 40 % of each part
    rot = Rotation.random(random_state=rng).as_matrix()
    t = rng.normal(size=3) * 0.1
    moved = model @ rot.T + t                         # the truth takes moved back: R^T (x - t)
    res = reglib.register_points(moved, target, method="icp", rng=seed)
    m = np.asarray(res.transform.linear.matrix)
    assert _angle(m[:, :3] @ rot) < 2.0
    assert np.abs(res.transform(moved) - model).mean() < 0.003
    assert res.converged and res.reason is None


def test_a_pose_without_support_says_so() -> None:
    rng = np.random.default_rng(4)
    plane = np.c_[rng.uniform(0, 1, size=(3000, 2)), np.zeros(3000)]
    sphere = rng.normal(size=(3000, 3))
    sphere = 0.3 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + [5.0, 5.0, 5.0]
    res = reglib.register_points(sphere, plane, method="icp", rng=0)
    assert not res.converged
    assert res.reason in REGISTRATION_REASONS


def test_support_reasons() -> None:
    assert support_reason(Support(overlap=0.05, residual=0.5, features=None)) == "small_overlap"
    assert support_reason(Support(overlap=0.5, residual=3.0, features=None)) == "large_residual"
    assert support_reason(Support(overlap=0.5, residual=1.2, features=0.1)) == "weak_features"
    assert support_reason(Support(overlap=0.5, residual=0.5, features=0.1)) is None   # a twin's inliers
    assert support_reason(Support(overlap=0.3, residual=0.8, features=0.9)) is None


def test_reason_in_the_registration_json() -> None:
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(200, 3))
    res = reglib.register_points(pts, pts + 0.01, method="icp", options={"init": "given"}, rng=0)
    d = res.to_dict()
    assert "reason" in d and d["reason"] is None
    assert Registration.from_dict(d).reason is None
    d["reason"] = "small_overlap"
    assert Registration.from_dict(d).reason == "small_overlap"
    del d["reason"]                                   # optional: older answers have none
    assert Registration.from_dict(d).reason is None
    d["reason"] = 3
    with pytest.raises(reglib.InputError, match="reason"):
        Registration.from_dict(d)


def test_icp_hmrf_takes_the_feature_start() -> None:
    scan = SCANS / "table_scene_mug_stereo_textured.npz"
    if not scan.exists():
        pytest.skip("shared scans not present")
    grid = np.load(scan)["xyz"].astype(np.float64)[::4, ::4]
    rot = np.array([[np.cos(2.6), 0.0, np.sin(2.6)], [0.0, 1.0, 0.0], [-np.sin(2.6), 0.0, np.cos(2.6)]])
    model = grid[:, :110] @ rot.T + [0.1, 0.0, 0.0]          # 149 degrees about y
    target = grid[:, 50:].reshape(-1, 3)
    target = target[np.isfinite(target).all(1)]
    res = reglib.register_points(model, target, method="icp-hmrf", options={"init": "features"}, rng=0)
    m = np.asarray(res.transform.linear.matrix)
    assert _angle(m[:, :3] @ rot) < 1.0
    assert res.converged


def test_the_client_result_carries_the_reason() -> None:
    client_results = pytest.importorskip("reglib_client.results")
    rng = np.random.default_rng(6)
    plane = np.c_[rng.uniform(0, 1, size=(2000, 2)), np.zeros(2000)]
    sphere = rng.normal(size=(2000, 3))
    sphere = 0.3 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + 5.0
    failed = reglib.register_points(sphere, plane, method="icp", rng=0)
    parsed = client_results.RegisterResult.from_json(failed.to_dict())
    assert parsed.reason == failed.reason and parsed.reason in REGISTRATION_REASONS
    assert not parsed.converged
    ok = reglib.register_points(plane, plane + 0.01, method="icp", options={"init": "given"}, rng=0)
    assert client_results.RegisterResult.from_json(ok.to_dict()).reason is None
