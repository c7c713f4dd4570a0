"""Tests of the color-assisted probabilistic rigid registration (``color-gmm``).

Ground truth is made: a painted plane cut into two overlapping windows (geometry cannot tell
where they overlap, color can), and colored surfaces moved by known rigid motions.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reglib.errors import InputError
from reglib.registration._color_gmm import ColorGMMOptions, color_gmm_register

from .conftest import bumpy, far_partial_pair


def _rotation(axis, degrees):
    """Rotation by ``degrees`` about ``axis`` (scipy's, independent of the library)."""
    return Rotation.from_rotvec(np.deg2rad(degrees) * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix()


def _angle(rot):
    return float(np.degrees(Rotation.from_matrix(rot).magnitude()))


def _painted_plane(n, rng):
    """Points on the plane z = 0 in [0, 1]^2 with a smooth grey-level pattern."""
    xy = rng.uniform(0, 1, (n, 2))
    lum = 0.5 + 0.4 * np.sin(2 * np.pi * 0.7 * xy[:, 0]) * np.cos(2 * np.pi * 1.5 * xy[:, 1])
    return np.c_[xy, np.zeros(n)], np.repeat(lum[:, None], 3, 1)


def _colored_surface(n, rng):
    xy = rng.uniform(-1, 1, (n, 2))
    z = 0.3 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1]) + 0.2 * xy[:, 0] ** 2
    pts = np.c_[xy, z]
    col = np.c_[0.5 + 0.4 * np.sin(3 * xy[:, 0]), 0.5 + 0.4 * np.cos(2 * xy[:, 1]), np.full(n, 0.3)]
    return pts, col


def _windows(shift, n=4000, seed=0):
    rng = np.random.default_rng(seed)
    pts, col = _painted_plane(n, rng)
    a, b = pts[:, 0] < 1 - shift, pts[:, 0] > shift
    return pts[a], col[a], pts[b], col[b]


@pytest.mark.parametrize("field, value", [("n_components", 1), ("n_components", 3001), ("luminance_bins", 0),
                                          ("chroma_bins", 17), ("outlier", 1.0), ("outlier", -0.1),
                                          ("max_iter", 0), ("tol", 0.0), ("max_points", 5),
                                          ("max_points", 3001), ("equalize", "yes"), ("init", "identity"),
                                          ("feature_iter", 5)])
def test_options_reject_bad_values(field, value):
    with pytest.raises(InputError, match=field):
        ColorGMMOptions(**{field: value})


@pytest.mark.slow
def test_color_pulls_a_plane_sliding_in_itself_towards_the_truth():
    # The windows overlap where x in [0.1, 0.9]; in the common frame the truth is the identity,
    # while the two patches' shapes agree best when slid by 0.1 onto each other (where the
    # centroid start puts them). Color removes most of that offset (not all of it: the partial
    # overlap biases the mixture, see the benchmark); without color the offset stays.
    m, mc, t, tc = _windows(0.1)
    opts = ColorGMMOptions(init="centroid")
    fit = color_gmm_register(m, t, opts, np.random.default_rng(0), model_colors=mc, target_colors=tc)
    grey = color_gmm_register(m, t, opts, np.random.default_rng(0), model_colors=np.full_like(mc, 0.5),
                              target_colors=np.full_like(tc, 0.5))
    assert abs(grey.matrix[0, 3]) > 0.08
    assert abs(fit.matrix[0, 3]) < 0.05
    assert np.abs(fit.matrix[1:, 3]).max() < 0.01
    assert _angle(fit.matrix[:, :3]) < 0.5


@pytest.mark.slow
def test_recovers_a_known_motion_of_a_colored_surface():
    rng = np.random.default_rng(2)
    pts, col = _colored_surface(1500, rng)
    rot, trans = _rotation([1, 2, 3], 25), np.array([0.3, -0.2, 0.5])
    target = pts @ rot.T + trans + rng.normal(scale=0.005, size=pts.shape)
    fit = color_gmm_register(pts, target, ColorGMMOptions(), rng, model_colors=col,
                             target_colors=np.clip(col + rng.normal(scale=0.02, size=col.shape), 0, 1))
    assert _angle(fit.matrix[:, :3] @ rot.T) < 0.5
    np.testing.assert_allclose(fit.matrix[:, 3], trans, atol=0.01)
    assert fit.converged


def test_two_dimensional_points():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-1, 1, (800, 2))
    col = np.c_[0.5 + 0.4 * np.sin(3 * xy[:, 0]), 0.5 + 0.4 * np.cos(3 * xy[:, 1]), np.full(800, 0.5)]
    a = np.deg2rad(15)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    fit = color_gmm_register(xy, xy @ rot.T + [2.0, 1.0], ColorGMMOptions(), rng, model_colors=col,
                             target_colors=col)
    assert fit.matrix.shape == (2, 3)
    np.testing.assert_allclose(fit.matrix, np.c_[rot, [2.0, 1.0]], atol=0.01)


def test_large_input_is_subsampled_and_deterministic():
    rng = np.random.default_rng(4)
    pts, col = _colored_surface(60000, rng)
    rot, trans = _rotation([0, 1, 1], 15), np.array([0.1, 0.2, -0.1])
    target = pts @ rot.T + trans
    copy_pts, copy_col = pts.copy(), col.copy()
    opts = ColorGMMOptions(max_points=300, n_components=60)
    a = color_gmm_register(pts, target, opts, np.random.default_rng(7), model_colors=col, target_colors=col)
    b = color_gmm_register(pts, target, opts, np.random.default_rng(7), model_colors=col, target_colors=col)
    np.testing.assert_array_equal(a.matrix, b.matrix)
    assert _angle(a.matrix[:, :3] @ rot.T) < 1.0
    np.testing.assert_array_equal(pts, copy_pts)  # inputs untouched
    np.testing.assert_array_equal(col, copy_col)


def _paint(points):
    return np.c_[0.5 + 0.4 * np.sin(4 * points[:, 0]), 0.5 + 0.4 * np.cos(3 * points[:, 1]), np.full(len(points), 0.5)]


def test_default_start_is_the_feature_start():
    assert ColorGMMOptions().init == "features"


def test_feature_start_registers_a_partial_scan_rotated_by_130_degrees():
    model, seen, target, rot, trans = far_partial_pair()
    fit = color_gmm_register(model, target, ColorGMMOptions(init="features", max_points=600),
                             np.random.default_rng(1), model_colors=_paint(model), target_colors=_paint(seen))
    assert _angle(fit.matrix[:, :3] @ rot.T) < 2.0
    np.testing.assert_allclose(fit.matrix[:, 3], trans, atol=0.06)   # 2.5 % of the extent


def test_given_starts_from_the_callers_pose():
    # Moving the model so that its centroid lies on the target's makes the caller's pose the
    # centroid start: init="given" then gives init="centroid"'s answer, composed with that move.
    rng = np.random.default_rng(3)
    model = bumpy(rng.uniform(-1, 1, (400, 2)))
    target = bumpy(rng.uniform(-1, 1, (400, 2)))
    target = target[target[:, 0] > -0.3]
    colors = {"model_colors": _paint(model), "target_colors": _paint(target)}
    target = target @ _rotation([1, 0, 2], 10).T + [0.2, 0.0, 0.1]
    shift = target.mean(0) - model.mean(0)
    centroid = color_gmm_register(model, target, ColorGMMOptions(max_iter=30, init="centroid"),
                                  np.random.default_rng(0), **colors)
    given = color_gmm_register(model + shift, target, ColorGMMOptions(max_iter=30, init="given"),
                               np.random.default_rng(0), **colors)
    np.testing.assert_allclose(given.matrix[:, :3], centroid.matrix[:, :3], atol=1e-8)
    np.testing.assert_allclose(given.matrix[:, :3] @ shift + given.matrix[:, 3], centroid.matrix[:, 3], atol=1e-8)
    unmoved = color_gmm_register(model, target, ColorGMMOptions(max_iter=30, init="given"),
                                 np.random.default_rng(0), **colors)
    assert np.abs(unmoved.matrix - centroid.matrix).max() > 1e-3
