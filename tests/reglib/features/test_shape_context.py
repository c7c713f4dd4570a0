"""Tests of reglib.features._shape_context: descriptors, chi^2 cost, one-to-one matching."""
import numpy as np
import pytest

from reglib.errors import InputError
from reglib.features import (
    chi2_cost,
    match_shape_contexts,
    rotate_bins,
    shape_context,
)


def _shape(n=40, seed=0):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pts = np.c_[np.cos(t) + 0.4 * np.cos(2 * t), np.sin(t) + 0.3 * np.sin(3 * t)]
    return pts + np.random.default_rng(seed).normal(0, 1e-3, pts.shape)


def _rot(deg):
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def test_shape_and_normalization():
    h = shape_context(_shape(), n_angle=8, n_radius=4)
    assert h.shape == (40, 32)
    assert np.allclose(h.sum(1), 1.0)
    assert (h >= 0).all()


def test_empty_and_single_point():
    assert shape_context(np.zeros((0, 2))).shape == (0, 60)
    assert np.array_equal(shape_context([[1.0, 2.0]]), np.zeros((1, 60)))


def test_counts_match_hand_computed_bins():
    # point 0 at the origin sees (1, 0) at angle 0 and (0, 1) at 90 degrees; mean distance = (1 + 1 + sqrt 2) / 3
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    h = shape_context(pts, n_angle=4, n_radius=5).reshape(3, 5, 4)
    md = (2 + np.sqrt(2)) / 3
    r_bin = int(np.searchsorted(np.geomspace(0.125, 2.0, 5), 1.0 / md, side="right"))
    assert h[0, r_bin, 0] == pytest.approx(0.5)
    assert h[0, r_bin, 1] == pytest.approx(0.5)


def test_scale_and_translation_invariance():
    pts = _shape()
    assert np.allclose(shape_context(pts), shape_context(3.0 * pts + [5.0, -2.0]))


def test_rotation_by_one_bin_is_a_cyclic_shift():
    pts = _shape()
    h = shape_context(pts, n_angle=12)
    hr = shape_context(pts @ _rot(30.0).T, n_angle=12)
    assert np.abs(rotate_bins(h, 1, n_angle=12) - hr).sum(1).mean() < 0.05
    assert np.abs(h - hr).sum(1).mean() > 0.5


def test_rotation_invariant_option():
    pts = _shape()
    h = shape_context(pts, rotation_invariant=True)
    h2 = shape_context(pts @ _rot(77.0).T, rotation_invariant=True)
    assert np.abs(h - h2).sum(1).mean() < 0.05
    assert np.abs(shape_context(pts) - shape_context(pts @ _rot(77.0).T)).sum(1).mean() > 0.5


def test_support_excludes_points():
    pts = _shape()
    far = np.r_[pts, [[50.0, 50.0]]]
    support = np.r_[np.ones(len(pts), bool), False]
    assert np.allclose(shape_context(far, support=support)[:-1], shape_context(pts))


def test_chi2_cost_values():
    a = np.array([[0.5, 0.5, 0.0], [1.0, 0.0, 0.0]])
    b = np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 1.0]])
    c = chi2_cost(a, b)
    def chi2(p, q):
        return 0.5 * sum((x - y) ** 2 / (x + y) for x, y in zip(p, q, strict=True) if x + y > 0)

    brute = np.array([[chi2(p, q) for q in b] for p in a])
    assert np.allclose(c, brute)
    assert c[0, 0] == 0.0 and c[1, 1] == pytest.approx(1.0)


def test_match_recovers_permutation_and_rejects_extra_points():
    pts = _shape(50)
    perm = np.random.default_rng(1).permutation(50)
    extra = np.random.default_rng(2).uniform(-3, 3, (5, 2)) * 10
    target = np.r_[pts[perm], extra]
    cost = chi2_cost(shape_context(pts), shape_context(target, support=np.r_[np.ones(50, bool), np.zeros(5, bool)]))
    ia, ib = match_shape_contexts(cost, dummy_cost=0.25)
    assert np.array_equal(ia, np.sort(ia))
    assert (ib < 50).all()
    assert np.mean(perm[ib] == ia) > 0.95


def test_match_prefers_dummy_when_costs_are_high():
    ia, ib = match_shape_contexts(np.array([[0.9, 0.95], [0.05, 0.9]]), dummy_cost=0.2)
    assert ia.tolist() == [1] and ib.tolist() == [0]
    ia, ib = match_shape_contexts(np.zeros((0, 3)))
    assert ia.shape == (0,) and ib.shape == (0,)


def test_errors():
    with pytest.raises(InputError, match="points"):
        shape_context(np.zeros((5, 3)))
    with pytest.raises(InputError, match="finite"):
        shape_context([[0.0, np.nan], [1.0, 1.0]])
    with pytest.raises(InputError, match="n_angle"):
        shape_context(_shape(), n_angle=0)
    with pytest.raises(InputError, match="r_outer"):
        shape_context(_shape(), r_inner=2.0, r_outer=1.0)
    with pytest.raises(InputError, match="share K"):
        chi2_cost(np.ones((2, 3)), np.ones((2, 4)))
    with pytest.raises(InputError, match="cost"):
        match_shape_contexts(np.ones(3))
    with pytest.raises(InputError, match="support"):
        shape_context(_shape(), support=np.ones(3, bool))
