"""Tests of reglib.register_points: ground truth made by warping point sets with known maps.

The contract every method keeps (result shapes and fields, its JSON form, its input errors) is
in test_methods.py; here are the behaviours of the non-rigid and CPD methods.
"""

import numpy as np
import pytest

from reglib import CPDOptions, InputError, RegistrationOptions, register_points


def _contour(n=80):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[np.cos(t) + 0.4 * np.cos(2 * t), np.sin(t) + 0.3 * np.sin(3 * t)]


def _rot2(deg):
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _bend(pts):
    """A smooth non-rigid deformation (known ground truth)."""
    return pts + 0.08 * np.sin(2.0 * pts[:, ::-1])


def _rot3(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@pytest.mark.parametrize("deg", [60.0, 120.0, 180.0])
def test_l2e_recovers_large_rotations(deg):
    model = _contour()
    truth = _bend(model) @ _rot2(deg).T
    res = register_points(model, truth, rng=0)
    assert np.linalg.norm(res.transform(model) - truth, axis=1).mean() < 0.03


def test_rotation_off_fails_at_180_degrees():
    model = _contour()
    truth = model @ _rot2(180.0).T
    res = register_points(model, truth, options={"rotation": False}, rng=0)
    assert np.linalg.norm(res.transform(model) - truth, axis=1).mean() > 0.3


def test_l2e_ignores_outliers_and_missing_parts():
    rng = np.random.default_rng(1)
    model = _contour(100)
    truth = _bend(model)
    target = np.r_[truth[:70], rng.uniform(-2, 2, (30, 2))]  # 30 % of the shape missing, 30 outliers
    res = register_points(model, target, options={"rotation": False}, rng=0)
    err = np.linalg.norm(res.transform(model) - truth, axis=1)
    assert np.median(err[:70]) < 0.03
    assert (res.correspondence[:70] == np.arange(70)).mean() > 0.8


def test_cpd_rigid_and_affine_recover_linear_maps():
    rng = np.random.default_rng(2)
    model = _contour()
    rigid = 1.3 * model @ _rot2(25.0).T + [1.0, 2.0]
    res = register_points(model, rigid, method="cpd-rigid", rng=0)
    assert np.abs(res.transform(model) - rigid).max() < 1e-3
    assert res.transform.n_centers == 0 and res.transform.linear.kind == "affine"
    a = np.array([[1.2, 0.3], [-0.1, 0.8]])
    affine = model @ a.T + [-2.0, 0.5] + rng.normal(0, 1e-4, model.shape)
    res = register_points(model, affine, method="cpd-affine", rng=0)
    assert np.abs(res.transform(model) - affine).max() < 2e-3


def test_cpd_low_rank_agrees_with_full():
    model = _contour()
    target = _bend(model)
    full = register_points(model, target, method="cpd", rng=0)
    low = register_points(model, target, method="cpd", options=CPDOptions(low_rank=True, n_eig=30), rng=0)
    assert np.linalg.norm(low.transform(model) - target, axis=1).mean() < 0.02
    assert np.linalg.norm(low.transform(model) - full.transform(model), axis=1).mean() < 0.02


def test_3d_rotated_surface_with_subsampling():
    rng = np.random.default_rng(3)
    uv = rng.uniform(-1, 1, (1500, 2))
    model = np.c_[uv, 0.4 * np.sin(2 * uv[:, 0]) + 0.2 * uv[:, 1] ** 2 + 0.3 * uv[:, 0] * uv[:, 1]]
    model[:, 0] *= 1.6  # distinct principal axes
    truth = (model + 0.05 * np.sin(2 * model[:, ::-1])) @ _rot3(rng).T + [5.0, 0.0, -1.0]
    target = truth[rng.permutation(len(truth))]
    res = register_points(model, target, options={"max_points": 400}, rng=0)
    err = np.linalg.norm(res.transform(model) - truth, axis=1)
    assert np.median(err) < 0.05, np.median(err)  # the surface spans about 3.5 units


def test_same_seed_same_answer():
    model = _contour()
    target = _bend(model) @ _rot2(70.0).T
    a = register_points(model, target, rng=5)
    b = register_points(model, target, rng=5)
    assert np.array_equal(a.transform(model), b.transform(model))


def test_duplicates_and_all_outlier_target_do_not_crash():
    model = np.r_[_contour(), _contour()[:10]]
    res = register_points(model, _bend(model), rng=0)
    assert res.correspondence.shape == (90,)
    junk = np.random.default_rng(4).uniform(-5, 5, (60, 2))
    for method in ("l2e", "cpd", "cpd-rigid", "cpd-affine"):
        res = register_points(_contour(), junk, method=method, rng=0)
        assert np.isfinite(res.transform(_contour())).all()
    same = np.zeros((10, 2))
    assert np.isfinite(register_points(same, same + 1.0, rng=0).transform(same)).all()


def test_errors():
    good = _contour()
    with pytest.raises(InputError, match="model"):
        register_points(np.zeros((10, 4)), good)
    with pytest.raises(InputError, match="dimension"):
        register_points(good, np.zeros((10, 3)))
    with pytest.raises(InputError, match="finite"):
        register_points(good, np.r_[good[:-1], [[np.nan, 0.0]]])
    with pytest.raises(InputError, match="at least"):
        register_points(good[:3], good)
    with pytest.raises(InputError, match="at least"):
        register_points(good, good[:1], method="cpd-rigid")
    with pytest.raises(InputError, match="method"):
        register_points(good, good, method="tps")
    with pytest.raises(InputError, match="unknown field"):
        register_points(good, good, options={"n_round": 3})
    with pytest.raises(InputError, match="beta"):
        CPDOptions(beta=-1.0)
    with pytest.raises(InputError, match="n_rounds"):
        RegistrationOptions(n_rounds=0)


def test_l2e_outlier_heavy_target():
    # as many uniform outliers as shape points, over the shape's bounding box (the outlier series'
    # ratio 1); held on several seeds
    for seed in range(3):
        rng = np.random.default_rng(seed)
        model = _contour(100)
        truth = _bend(model)
        target = np.r_[truth, rng.uniform(-2.0, 2.0, (100, 2))][rng.permutation(200)]
        res = register_points(model, target, rng=0)
        err = np.linalg.norm(res.transform(model) - truth, axis=1)
        assert err.mean() < 0.05 and np.median(err) < 0.01, (seed, err.mean())  # the shape spans 3 units


def test_rotation_search_keeps_noisy_aligned_data():
    # noisy, unrotated target: the rotation search must not pick a wrong rotation
    rng = np.random.default_rng(0)
    model = _contour(100)
    truth = _bend(model)
    target = truth + rng.normal(0, 0.06, truth.shape)
    on = register_points(model, target, rng=0)
    off = register_points(model, target, options={"rotation": False}, rng=0)
    err_on = np.linalg.norm(on.transform(model) - truth, axis=1).mean()
    err_off = np.linalg.norm(off.transform(model) - truth, axis=1).mean()
    assert err_on < 0.04 and err_on < 1.2 * err_off + 1e-3, (err_on, err_off)


def test_options_of_the_refinement_and_rotation_prior():
    model = _contour()
    target = _bend(model)
    plain = register_points(model, target, options={"n_refine": 0, "rotation": False}, rng=0)
    assert np.linalg.norm(plain.transform(model) - target, axis=1).mean() < 0.03
    with pytest.raises(InputError, match="outlier_weight"):
        RegistrationOptions(outlier_weight=1.0)
    with pytest.raises(InputError, match="rotation_margin"):
        RegistrationOptions(rotation_margin=-0.1)
    with pytest.raises(InputError, match="n_refine"):
        RegistrationOptions(n_refine=-1)
    with pytest.raises(InputError, match="outlier_passes"):
        RegistrationOptions(outlier_passes=-1)


@pytest.mark.parametrize("method, field, value", [
    ("l2e", "n_rounds", 101), ("l2e", "n_angle", 361), ("l2e", "n_radius", 51), ("l2e", "n_refine", 1001),
    ("l2e", "max_points", 3001), ("cpd", "max_points", 5001), ("cpd", "max_iter", 10001), ("cpd", "n_eig", 1001),
])
def test_counts_that_would_run_without_end_are_refused(method, field, value):
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5]] * 4) + np.arange(20)[:, None] * 0.01
    with pytest.raises(InputError, match=field):
        register_points(square, square, method=method, options={field: value})
