"""A probabilistic method's rigid answer checked by a robust fit from it (reglib.registration._polish)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from reglib import register_points
from reglib._verdict import MAX_POLISH_SHIFT, POOR_FIT, polish_reason
from reglib.registration._polish import polish_shift


def _blob(seed: int, n: int = 200):
    """A flattened Gaussian blob (extent about 4) and its rigid motion: target = model @ rot.T + shift."""
    rng = np.random.default_rng(seed)
    model = rng.normal(size=(n, 3)) * [1.0, 0.6, 0.3]
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return model, rot, np.array([0.2, -0.1, 0.1]), rng


def _far_points(rng: np.random.Generator, count: int, distance: float) -> np.ndarray:
    out = rng.normal(size=(count, 3))
    return distance * out / np.linalg.norm(out, axis=1, keepdims=True)


def _mean_error(res, truth: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(res.registered) - truth, axis=1).mean())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cpd_rigid_pulled_off_by_far_outliers_is_not_converged(seed: int) -> None:
    # 30 target points ten radii away: CPD with no outlier component gives them a share of the model and
    # settles off the blob (and shrinks or grows it), while its EM says it converged
    model, rot, shift, rng = _blob(seed)
    truth = model @ rot.T + shift
    target = np.r_[truth, _far_points(rng, 30, 10.0)]
    res = register_points(model, target, method="cpd-rigid", rng=0)
    assert _mean_error(res, truth) > 0.3  # the answer is wrong (the blob's spacing is about 0.2)
    assert not res.converged and res.reason == POOR_FIT


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cpd_rigid_right_answers_stay_converged(seed: int) -> None:
    # clean, noisy, and a part of the target missing: right answers, which the robust fit leaves where they are
    model, rot, shift, rng = _blob(seed)
    truth = model @ rot.T + shift
    noisy = truth + rng.normal(scale=0.02, size=truth.shape)
    for target in (truth, noisy, noisy[model[:, 0] < np.quantile(model[:, 0], 0.8)]):
        res = register_points(model, target, method="cpd-rigid", rng=0)
        assert _mean_error(res, truth) < 0.05
        assert res.converged and res.reason is None


def test_polish_shift_is_zero_at_a_perfect_fit_and_measures_an_offset() -> None:
    model, _, _, rng = _blob(3, 400)
    tree = cKDTree(model)
    assert polish_shift(model, tree, scale=False) < 1e-6
    spacing = float(np.median(tree.query(model, k=2)[0][:, 1]))
    off = model + [0.5, 0.0, 0.0]  # about two and a half spacings off
    shift = polish_shift(off, tree, scale=False)
    assert shift == pytest.approx(0.5 / spacing, rel=0.2)
    assert polish_reason(shift) == POOR_FIT and polish_reason(0.5 * MAX_POLISH_SHIFT) is None
