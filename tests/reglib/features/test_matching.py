"""Tests of reglib.features._matching: nearest neighbours, Lowe's ratio test and the mutual check."""
from __future__ import annotations

import numpy as np
import pytest

from reglib.errors import InputError
from reglib.features import match_descriptors, match_unit_descriptors, select_matches


def _unit(rng: np.random.Generator, n: int, dim: int = 32) -> np.ndarray:
    d = rng.random((n, dim)).astype(np.float32)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- select_matches

def test_select_matches_applies_the_ratio_test_and_the_mutual_check():
    nearest = np.array([2, 0, 0, -1])
    first = np.array([0.1, 0.30, 0.2, 0.0])
    second = np.array([1.0, 0.35, 0.5, 1.0])
    ia, ib = select_matches(nearest, first, second, ratio=0.8)
    assert ia.tolist() == [0, 2] and ib.tolist() == [2, 0]   # row 1 ambiguous, row 3 has no neighbour
    assert ia.dtype == ib.dtype == np.intp
    ia, ib = select_matches(nearest, first, second, ratio=1.0)
    assert ia.tolist() == [0, 1, 2]                           # ratio 1: every nearest neighbour
    back = np.array([1, 3, 0])                                # b[0]'s nearest is a[1], b[2]'s is a[0]
    ia, ib = select_matches(nearest, first, second, ratio=1.0, back=back)
    assert ia.tolist() == [0, 1] and ib.tolist() == [2, 0]


def test_select_matches_without_a_second_neighbour():
    nearest, first = np.array([0, 1]), np.array([0.1, 0.1])
    assert select_matches(nearest, first, np.array([np.nan, 0.5]), ratio=0.8)[0].tolist() == [1]
    assert select_matches(nearest, first, np.array([np.inf, 0.5]), ratio=0.8)[0].tolist() == [0, 1]
    empty = select_matches(np.zeros(0, np.intp), np.zeros(0), np.zeros(0), ratio=0.8)
    assert empty[0].shape == empty[1].shape == (0,)


# ----------------------------------------------------------------------------- match_descriptors (L2)

def test_match_descriptors_recovers_a_permutation():
    rng = np.random.default_rng(0)
    d = rng.random((50, 128)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    perm = rng.permutation(50)
    ia, ib = match_descriptors(d, d[perm], ratio=0.99)
    assert np.array_equal(ia, np.arange(50))
    assert np.array_equal(perm[ib], ia)
    ia, ib = match_descriptors(d, d[perm], ratio=1.0, mutual=True)
    assert len(ia) == 50


def test_ratio_test_and_mutual_check():
    a = np.array([[0.995, 0.005], [0.0, 1.0]], np.float32)
    b = np.array([[1.0, 0.0], [0.99, 0.01], [0.0, 1.0]], np.float32)
    ia, ib = match_descriptors(a, b, ratio=0.8)
    assert ia.tolist() == [1] and ib.tolist() == [2]  # the first is ambiguous
    ia, _ = match_descriptors(a, b, ratio=1.0)
    assert ia.tolist() == [0, 1]
    # b[0] and b[1] both want a[0]; only b[0] <-> a[0] is mutual
    ia, ib = match_descriptors(b, a, ratio=1.0, mutual=True)
    assert ia.tolist() == [0, 2] and ib.tolist() == [0, 1]
    e = np.zeros((0, 2), np.float32)
    assert match_descriptors(e, a)[0].shape == (0,)
    assert match_descriptors(a, b[:1], ratio=1.0)[0].tolist() == [0, 1]


def test_match_descriptors_ratio_needs_a_second_neighbour():
    a = np.array([[0.0, 1.0]], np.float32)
    assert match_descriptors(a, a, ratio=0.8)[0].shape == (0,)       # one row in b: no second neighbour
    assert match_descriptors(a, a, ratio=1.0)[0].tolist() == [0]


# ----------------------------------------------------------------------------- match_unit_descriptors

def test_match_unit_descriptors_recovers_a_permutation_and_agrees_with_l2():
    rng = np.random.default_rng(3)
    a = _unit(rng, 60)
    perm = rng.permutation(60)
    b = a[perm] + rng.normal(0, 0.01, (60, 32)).astype(np.float32)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    ia, ib = match_unit_descriptors(a, b)
    assert ia.tolist() == list(range(60)) and np.array_equal(perm[ib], ia)
    # on unit vectors the cosine ranking is the Euclidean one
    other = _unit(rng, 40)
    for ratio, mutual in [(0.9, False), (0.95, True), (1.0, True)]:
        u = match_unit_descriptors(a, other, ratio=ratio, mutual=mutual)
        e = match_descriptors(a, other, ratio=ratio, mutual=mutual)
        assert np.array_equal(u[0], e[0]) and np.array_equal(u[1], e[1])


def test_match_unit_descriptors_ratio_ties_and_mutual():
    d = np.eye(4, dtype=np.float32)
    b = np.array([[1, 0, 0, 0], [0.8, 0.6, 0, 0], [0, 0, 1, 0]], np.float32)
    ia, ib = match_unit_descriptors(d, b, ratio=1.0, mutual=False)
    # a[3] is orthogonal to every row of b: an exact tie, resolved to the lower index
    assert ia.tolist() == [0, 1, 2, 3] and ib.tolist() == [0, 1, 2, 0]
    # b[1] = (0.8, 0.6, 0, 0) is nearer a[0] than a[1]: only a[0] <-> b[0] and a[2] <-> b[2] are mutual
    ia, ib = match_unit_descriptors(d, b, ratio=1.0, mutual=True)
    assert ia.tolist() == [0, 2] and ib.tolist() == [0, 2]
    # a[0]: distance 0 to b[0], 0.63 to b[1]: passes 0.5; a[1]: 0.89 against 1.41: fails 0.5
    ia, _ = match_unit_descriptors(d, b, ratio=0.5, mutual=False)
    assert ia.tolist() == [0, 2]
    one = match_unit_descriptors(d, b[:1], ratio=0.5, mutual=False)  # one row in b: kept (second = inf)
    assert one[0].tolist() == [0, 1, 2, 3]


def test_match_unit_descriptors_empty_and_errors():
    d = np.eye(3, dtype=np.float32)
    ia, ib = match_unit_descriptors(d[:0], d)
    assert ia.shape == ib.shape == (0,) and ia.dtype == np.intp
    with pytest.raises(InputError, match="desc_a"):
        match_unit_descriptors(d, d[:, :2])
    with pytest.raises(InputError, match="ratio"):
        match_unit_descriptors(d, d, ratio=1.5)
