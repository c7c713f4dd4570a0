"""Tests of the density adaptive rigid registration (``density-adaptive``).

Ground truth is made: surfaces sampled with known density changes, moved by known motions.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reglib.errors import InputError
from reglib.registration._density_adaptive import (
    DensityAdaptiveOptions,
    density_adaptive_register,
    observation_weights,
)

from .conftest import bumpy, far_partial_pair


def _rotation(axis, degrees):
    """Rotation by ``degrees`` about ``axis`` (scipy's, independent of the library)."""
    return Rotation.from_rotvec(np.deg2rad(degrees) * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix()


def _angle(rot):
    return float(np.degrees(Rotation.from_matrix(rot).magnitude()))


def _surface(xy):
    return np.c_[xy, 0.3 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1]) + 0.2 * xy[:, 0] ** 2]


@pytest.mark.parametrize("field, value", [("n_components", 1), ("n_neighbors", 0), ("n_neighbors", 101),
                                          ("dim", 0), ("dim", 4), ("max_weight", 0.5), ("outlier", 1.0),
                                          ("max_iter", 0), ("tol", 0.0), ("max_points", 3001),
                                          ("init", "identity"), ("n_rotations", 0)])
def test_options_reject_bad_values(field, value):
    with pytest.raises(InputError, match=field):
        DensityAdaptiveOptions(**{field: value})


def test_dim_above_the_points_dimension_is_an_input_error():
    pts = np.random.default_rng(0).normal(size=(50, 2))
    with pytest.raises(InputError, match="dim"):
        density_adaptive_register(pts, pts, DensityAdaptiveOptions(dim=3), np.random.default_rng(0))


def test_weights_undo_a_tenfold_density_step_on_a_surface():
    rng = np.random.default_rng(1)
    dense = rng.uniform([-1, -1], [0, 1], (5000, 2))
    sparse = rng.uniform([0, -1], [1, 1], (500, 2))
    pts = _surface(np.r_[dense, sparse])
    w = observation_weights(pts, 10, 2, 100.0)
    assert w.shape == (5500,)
    np.testing.assert_allclose(w.mean(), 1.0)
    ratio = np.median(w[5000:]) / np.median(w[:5000])
    assert 7.0 < ratio < 13.0
    # both halves now weigh about the same in total
    assert 0.7 < w[5000:].sum() / w[:5000].sum() < 1.4


def test_weights_are_clipped_and_degenerate_sets_get_ones():
    rng = np.random.default_rng(2)
    pts = np.r_[rng.normal(size=(200, 3)) * 0.01, [[50.0, 50.0, 50.0]]]  # one far outlier
    w = observation_weights(pts, 5, 2, 3.0)
    assert w.max() / np.median(w) <= 3.0 * (1 + 1e-9)
    np.testing.assert_array_equal(observation_weights(np.zeros((1, 3)), 5, 2, 3.0), [1.0])


def _density_step_pair():
    rng = np.random.default_rng(4)
    rot, trans = _rotation([1, 2, 3], 25), np.array([0.3, 0.2, -0.4])
    # model: ten times denser on the left half; target: uniform
    model = _surface(np.r_[rng.uniform([-1, -1], [0, 1], (3000, 2)), rng.uniform([0, -1], [1, 1], (300, 2))])
    target = _surface(rng.uniform(-1, 1, (1000, 2))) @ rot.T + trans
    return model, target, rot, trans


def test_recovers_a_known_motion_between_scans_of_different_density():
    # both this test and the next start from the centroids, so that only the weights differ
    model, target, rot, trans = _density_step_pair()
    fit = density_adaptive_register(model, target, DensityAdaptiveOptions(init="centroid"), np.random.default_rng(0))
    assert _angle(fit.matrix[:, :3] @ rot.T) < 1.0
    np.testing.assert_allclose(fit.matrix[:, 3], trans, atol=0.02)


def test_without_the_weights_the_dense_half_dominates():
    model, target, rot, _ = _density_step_pair()
    fit = density_adaptive_register(model, target, DensityAdaptiveOptions(max_weight=1.0, init="centroid"),
                                    np.random.default_rng(0))
    assert _angle(fit.matrix[:, :3] @ rot.T) > 3.0


def test_two_dimensional_contour_uses_curve_weights_by_default():
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    contour = np.c_[np.cos(t) + 0.4 * np.cos(2 * t), np.sin(t) + 0.3 * np.sin(3 * t)]
    a = np.deg2rad(15)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    fit = density_adaptive_register(contour, contour @ rot.T + [1.0, 0.5], DensityAdaptiveOptions(max_weight=3.0),
                                    np.random.default_rng(0))
    assert fit.matrix.shape == (2, 3)
    np.testing.assert_allclose(fit.matrix, np.c_[rot, [1.0, 0.5]], atol=0.03)


def test_large_input_is_subsampled_and_deterministic():
    rng = np.random.default_rng(5)
    pts = _surface(rng.uniform(-1, 1, (60000, 2)))
    rot = _rotation([0, 0, 1], 20)
    target = pts @ rot.T
    before = pts.copy()
    opts = DensityAdaptiveOptions(max_points=300, n_components=60)
    a = density_adaptive_register(pts, target, opts, np.random.default_rng(9))
    b = density_adaptive_register(pts, target, opts, np.random.default_rng(9))
    np.testing.assert_array_equal(a.matrix, b.matrix)
    assert _angle(a.matrix[:, :3] @ rot.T) < 2.0  # 300 of 60000 points: a coarse fit
    np.testing.assert_array_equal(pts, before)


def test_default_start_is_the_feature_start():
    assert DensityAdaptiveOptions().init == "features"


def test_feature_start_registers_a_partial_scan_rotated_by_130_degrees():
    model, _, target, rot, trans = far_partial_pair()
    fit = density_adaptive_register(model, target, DensityAdaptiveOptions(init="features", max_points=600),
                                    np.random.default_rng(1))
    assert _angle(fit.matrix[:, :3] @ rot.T) < 3.5
    # 3-4 % of the extent: the partial overlap biases the scene mixture (0.08-0.12 over seeds 1-4;
    # the centroid start ends 100+ degrees off)
    np.testing.assert_allclose(fit.matrix[:, 3], trans, atol=0.1)


def test_given_starts_from_the_callers_pose():
    # Moving the model so that its centroid lies on the target's makes the caller's pose the
    # centroid start: init="given" then gives init="centroid"'s answer, composed with that move.
    rng = np.random.default_rng(3)
    model = bumpy(rng.uniform(-1, 1, (400, 2)))
    target = bumpy(rng.uniform(-1, 1, (400, 2)))
    target = target[target[:, 0] > -0.3] @ _rotation([1, 0, 2], 10).T + [0.2, 0.0, 0.1]
    shift = target.mean(0) - model.mean(0)
    centroid = density_adaptive_register(model, target, DensityAdaptiveOptions(max_iter=30, init="centroid"),
                                         np.random.default_rng(0))
    given = density_adaptive_register(model + shift, target, DensityAdaptiveOptions(max_iter=30, init="given"),
                                      np.random.default_rng(0))
    np.testing.assert_allclose(given.matrix[:, :3], centroid.matrix[:, :3], atol=1e-8)
    np.testing.assert_allclose(given.matrix[:, :3] @ shift + given.matrix[:, 3], centroid.matrix[:, 3], atol=1e-8)
    unmoved = density_adaptive_register(model, target, DensityAdaptiveOptions(max_iter=30, init="given"),
                                        np.random.default_rng(0))
    assert np.abs(unmoved.matrix - centroid.matrix).max() > 1e-3
