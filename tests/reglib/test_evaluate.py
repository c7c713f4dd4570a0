"""Tests of :func:`reglib._evaluate.evaluate` against known transforms and landmarks."""
from __future__ import annotations

import math

import numpy as np
import pytest

from reglib._evaluate import Evaluation, evaluate
from reglib._transforms import KernelWarp, LinearPart
from reglib.errors import InputError


def _affine(matrix):
    return KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.zeros(2), dst_scale=1.0,
                      linear=LinearPart(kind="affine", matrix=np.asarray(matrix, float)), beta=1.0,
                      centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))


def test_tre_rtre_rms_and_hausdorff_from_a_known_shift():
    rng = np.random.default_rng(0)
    pa = rng.uniform(0, 100, (20, 2))
    shift = _affine([[1, 0, 3.0], [0, 1, 4.0]])  # every landmark moved by (3, 4): 5 px off where b = a
    errors = np.zeros(20)
    errors[7] = 10.0  # one landmark of b placed 10 px further along x
    pb = pa.copy()
    pb[7, 0] += 10.0
    ev = evaluate(KernelWarp.identity(2), pa, pb, shape_b=(60, 80))
    assert np.allclose(ev.tre, errors)
    assert ev.median == 0.0 and ev.max == pytest.approx(10.0) and ev.mean == pytest.approx(0.5)
    assert ev.rms == pytest.approx(math.sqrt(100 / 20))
    assert ev.diagonal == pytest.approx(100.0)
    assert ev.rtre_max == pytest.approx(0.1) and np.allclose(ev.rtre, errors / 100.0)
    ev2 = evaluate(shift, pa, pa + [3.0, 4.0])
    assert np.allclose(ev2.tre, 0.0) and ev2.hausdorff == pytest.approx(0.0, abs=1e-9)
    assert ev2.rtre is None and ev2.rtre_median is None and ev2.fold_fraction is None
    assert np.allclose(ev2.registered, pa + [3.0, 4.0])


def test_hausdorff_is_between_sets_not_pairs():
    pa = np.array([[0.0, 0.0], [10.0, 0.0]])
    swapped = pa[::-1].copy()  # pairs 10 px off each, but the sets are the same
    ev = evaluate(KernelWarp.identity(2), pa, swapped)
    assert ev.mean == pytest.approx(10.0) and ev.hausdorff == pytest.approx(0.0)
    far = np.array([[0.0, 0.0], [10.0, 7.0]])
    assert evaluate(KernelWarp.identity(2), pa, far).hausdorff == pytest.approx(7.0)


def test_fold_fraction_over_a():
    pts = np.array([[5.0, 5.0]])
    assert evaluate(KernelWarp.identity(2), pts, pts, shape_a=(32, 40)).fold_fraction == 0.0
    mirror = _affine([[-1, 0, 0], [0, 1, 0]])  # Jacobian determinant -1 everywhere: a's pixels all fold
    assert evaluate(mirror, pts, pts, shape_a=(32, 40)).fold_fraction == pytest.approx(1.0)


def test_to_dict_and_dict_transform_and_empty():
    pa = np.array([[1.0, 2.0], [3.0, 4.0]])
    ev = evaluate(KernelWarp.identity(2).to_dict(), pa, pa + [0.0, 2.0], shape_a=(10, 10), shape_b=(30, 40))
    d = ev.to_dict()
    assert d["n_landmarks"] == 2 and d["tre"] == [2.0, 2.0] and d["rtre_median"] == pytest.approx(0.04)
    assert d["fold_fraction"] == 0.0 and d["registered"] == pa.tolist()
    empty = evaluate(KernelWarp.identity(2), np.zeros((0, 2)), np.zeros((0, 2)), shape_b=(5, 5))
    assert isinstance(empty, Evaluation) and empty.n_landmarks == 0 and empty.mean == 0.0
    assert empty.tre.shape == (0,) and empty.registered.shape == (0, 2) and empty.rtre_median == 0.0


def test_errors_are_named():
    pa = np.zeros((3, 2))
    with pytest.raises(InputError, match="same number of landmarks"):
        evaluate(KernelWarp.identity(2), pa, np.zeros((4, 2)))
    with pytest.raises(InputError, match="landmarks_b"):
        evaluate(KernelWarp.identity(2), pa, np.zeros((3, 3)))
    with pytest.raises(InputError, match="shape_b"):
        evaluate(KernelWarp.identity(2), pa, pa, shape_b=(0, 5))
    with pytest.raises(InputError, match="transform"):
        evaluate("identity", pa, pa)
    with pytest.raises(InputError, match="finite"):
        evaluate(KernelWarp.identity(2), pa, np.full((3, 2), np.nan))
