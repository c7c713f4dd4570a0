"""Tests of the dense stage's similarity evidence (reglib.dense._evidence: local_similarity, evidence_z,
evidence_over_no_motion) and of the guard's outcome it decides, with known shifts of scikit-image samples."""
from __future__ import annotations

import cv2
import numpy as np
import skimage.data

from reglib import KernelWarp
from reglib._transforms import LinearPart
from reglib.dense import DENSE_OUTCOMES, EVIDENCE_Z, DenseOptions, evidence_over_no_motion
from reglib.dense._evidence import evidence_z, local_similarity
from reglib.dense._guarding import guard
from reglib.dense._refine import working_frames
from reglib.dense._result import DenseFit


def _shift(dx: float, dy: float) -> KernelWarp:
    return KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.zeros(2), dst_scale=1.0,
                      linear=LinearPart(kind="affine", matrix=np.array([[1.0, 0, dx], [0, 1.0, dy]])), beta=1.0,
                      centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))


def _field(img: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(img, np.float32)[:, :, None]


def _camera_pair(dx: int = 6, dy: int = -4) -> tuple[np.ndarray, np.ndarray]:
    """a and b = a moved by (dx, dy) px (b(x + dx, y + dy) = a(x, y)): the true transform is a shift by (dx, dy)."""
    a = skimage.data.camera()[64:320, 64:320].astype(np.float32)
    b = cv2.warpAffine(a, np.float32([[1, 0, dx], [0, 1, dy]]), a.shape[::-1], borderMode=cv2.BORDER_REFLECT)
    return a, b


def test_local_similarity_is_highest_at_the_true_shift_and_nan_outside():
    a, b = _camera_pair()
    pts = np.array([[128.0, 128.0], [64.0, 100.0], [2.0, 2.0], [250.0, 128.0]])
    at_truth = local_similarity(_field(a), _field(b), _shift(6, -4), pts, 8)
    off = local_similarity(_field(a), _field(b), _shift(0, 0), pts, 8)
    assert at_truth.shape == (4,)
    np.testing.assert_allclose(at_truth[:2], 1.0, atol=1e-3)  # the same patch: NCC 1
    assert np.all(off[:2] < 0.9)
    assert np.isnan(at_truth[2])  # the patch leaves a
    assert np.isnan(at_truth[3])  # mapped beyond b's right border
    assert local_similarity(_field(a), _field(b), _shift(6, -4), np.zeros((0, 2)), 8).shape == (0,)


def test_evidence_z_ranks_the_true_shift_over_a_wrong_one_and_over_no_motion():
    a, b = _camera_pair()
    fa, fb = _field(a), _field(b)
    assert evidence_z(fa, fb, _shift(6, -4), _shift(0, 0), 16) > 5.0
    assert evidence_z(fa, fb, _shift(0, 0), _shift(6, -4), 16) < -5.0
    assert evidence_z(fa, fb, _shift(6, -4), _shift(6, -4), 16) == 0.0  # nothing differs: no evidence
    opts = DenseOptions(max_side=256)
    assert evidence_over_no_motion(a, b, _shift(6, -4), opts) >= EVIDENCE_Z
    # an answer 9 px off where b is a itself: the images rate it worse than no motion
    assert evidence_over_no_motion(a, a, _shift(9, 0), opts) <= -EVIDENCE_Z


def test_guard_keeps_a_dense_estimate_the_check_cannot_see_when_the_similarity_favours_it():
    # b: a moved by (6, -4) px and blurred hard (another rendering of the same structure: the check's distinct
    # peaks are gone, the similarity at the true place stays higher than at f0, 6 px off)
    a, b = _camera_pair()
    b = cv2.GaussianBlur(b, (0, 0), 6.0)
    size = a.shape[0]
    f0, truth = _shift(0, 0), _shift(6, -4)
    grid = np.mgrid[8:size - 8:8, 8:size - 8:8].reshape(2, -1).T[:, ::-1].astype(float)
    opts = DenseOptions(max_side=size)
    res = guard(working_frames(a, b, opts), f0, DenseFit(transform=truth, converged=True, src=grid, dst=truth(grid)),
                opts, np.random.default_rng(0), rounds=1)
    assert res.outcome == "kept" and not res.kept_first and res.transform is truth
    # the same guard with the two swapped: the wrong dense estimate is refused, f0 (now the true one) stays
    res = guard(working_frames(a, b, opts), truth, DenseFit(transform=f0, converged=True, src=grid, dst=grid),
                opts, np.random.default_rng(0), rounds=1)
    assert res.outcome == "no_support" and res.kept_first and res.transform is truth
    assert set(DENSE_OUTCOMES) == {"kept", "sparse_better", "no_support", "no_matches", "not_run"}
