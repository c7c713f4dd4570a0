"""Robust rigid ICP: options, robust weights, the global start, and recovery of known motions."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from reglib._validation import as_options
from reglib.errors import InputError
from reglib.options import option_specs
from reglib.registration._feature_start import feature_start
from reglib.registration._icp import ICPOptions, icp_register, refine_icp
from reglib.registration._losses import DEFAULT_TUNING, LOSSES, mad_scale, robust_weights
from reglib.registration._normals import estimate_normals
from reglib.registration._start import Start, rotation_hypotheses


def _surface(n: int, rng: np.random.Generator) -> np.ndarray:
    """A bumpy, asymmetric height field sampled at n random points (extent about 3)."""
    xy = rng.uniform(-1.0, 1.0, size=(n, 2)) * [1.5, 1.0]
    z = 0.3 * np.sin(2.0 * xy[:, 0]) * np.cos(3.0 * xy[:, 1]) + 0.25 * xy[:, 0] ** 2 + 0.1 * xy[:, 1]
    return np.c_[xy, z]


def _rotation(axis, degrees):
    """Rotation by ``degrees`` about ``axis`` (scipy's, independent of the library)."""
    return Rotation.from_rotvec(np.deg2rad(degrees) * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix()


def _moved(target: np.ndarray, rot: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """The model whose truth ``target = rot @ model + shift``."""
    return (target - shift) @ rot


def _angle_error(matrix: np.ndarray, rot: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(matrix[:, :3] @ rot.T).magnitude()))


# ----------------------------------------------------------------------------- options

@pytest.mark.parametrize(("fields", "match"), [
    ({"variant": "plane"}, r"`variant` must be one of \['point_to_point', 'point_to_plane'\]"),
    ({"loss": "bisquare"}, r"`loss` must be one of .*'tukey'"),
    ({"solver": "qr"}, r"`solver` must be one of"),
    ({"init": "pca"}, r"`init` must be one of"),
    ({"max_iter": 0}, r"`max_iter` must be a positive integer"),
    ({"max_iter": 10**6}, r"`max_iter` must be <= 1000"),
    ({"tuning": -1.0}, r"`tuning` must be > 0"),
    ({"scale": 0.0}, r"`scale` must be > 0"),
    ({"trim_ratio": 1.5}, r"`trim_ratio` must be <= 1"),
    ({"max_distance": float("nan")}, r"`max_distance` must be a finite number"),
    ({"n_rotations": 10**5}, r"`n_rotations` must be <= 4096"),
    ({"init_max_angle": 200.0}, r"`init_max_angle` must be <= 180"),
    ({"k_normals": 2}, r"`k_normals` must be an integer >= 3"),
])
def test_options_reject_bad_values(fields: dict, match: str) -> None:
    with pytest.raises(InputError, match=match):
        ICPOptions(**fields)


def test_options_are_frozen_and_reject_unknown_fields() -> None:
    opts = ICPOptions()
    with pytest.raises(AttributeError):
        opts.loss = "l2"  # type: ignore[misc]
    with pytest.raises(TypeError):
        ICPOptions(los="l2")  # type: ignore[call-arg]


def test_options_are_declared_with_todays_bounds() -> None:
    specs = {s.name: s for s in option_specs(ICPOptions)}
    assert specs["tol"].default == 1e-5 and specs["tol"].low_open
    assert (specs["max_iter"].low, specs["max_iter"].high) == (1, 1000)
    assert specs["trim_ratio"].optional and specs["trim_ratio"].default == 0.7
    assert specs["loss"].choices == LOSSES


def test_tolerance_was_renamed_tol() -> None:
    assert ICPOptions(tol=1e-6).tol == 1e-6
    with pytest.raises(InputError, match=r"`tolerance` was renamed to `tol`"):
        ICPOptions(tolerance=1e-6)  # type: ignore[call-arg]
    with pytest.raises(InputError, match=r"`tolerance` was renamed to `tol`"):
        as_options({"tolerance": 1e-6}, ICPOptions)


# ----------------------------------------------------------------------------- weights

@pytest.mark.parametrize("loss", [x for x in LOSSES if x not in ("l1", "trimmed")])
def test_weights_are_bounded_and_non_increasing(loss: str) -> None:
    r = np.linspace(0.0, 20.0, 401)
    w = robust_weights(r, 1.0, loss, DEFAULT_TUNING[loss])
    assert w.shape == r.shape
    assert (w >= 0).all() and np.isfinite(w).all()
    assert (np.diff(w) <= 1e-12).all()
    if loss != "l2":
        assert w[-1] < 0.1 * w[0]                      # far residuals lose their pull


def test_weights_of_the_hard_rejectors() -> None:
    r = np.array([0.0, 1.0, 2.0, 5.0, 10.0])
    np.testing.assert_array_equal(robust_weights(r, 1.0, "tukey", 4.0) > 0, [True, True, True, False, False])
    np.testing.assert_array_equal(robust_weights(r, 1.0, "max_distance", 3.0), [1, 1, 1, 0, 0])
    np.testing.assert_array_equal(robust_weights(r, 1.0, "max_distance", 3.0, max_distance=1.5), [1, 1, 0, 0, 0])
    np.testing.assert_array_equal(robust_weights(r, 1.0, "trimmed", 1.0, trim_ratio=0.6), [1, 1, 1, 0, 0])
    # VarTrimmed keeps the tight cluster and drops the gross errors
    mixed = np.r_[np.abs(np.random.default_rng(0).normal(size=70)) * 0.01, np.linspace(5, 10, 30)]
    assert robust_weights(mixed, 1.0, "trimmed", 1.0, trim_ratio=None).sum() == pytest.approx(70, abs=3)
    np.testing.assert_allclose(robust_weights(np.array([2.0]), 1.0, "huber", 1.0), [0.5])
    np.testing.assert_allclose(robust_weights(np.array([1.0]), 1.0, "cauchy", 1.0), [0.5])


@pytest.mark.parametrize("dof", [1, 2, 3])
def test_mad_scale_estimates_the_gaussian_sigma(dof: int) -> None:
    r = np.random.default_rng(dof).normal(scale=0.2, size=(200_000, dof))
    r_abs = np.abs(r[:, 0]) if dof == 1 else np.linalg.norm(r, axis=1)
    assert mad_scale(r_abs, dof) == pytest.approx(0.2, rel=0.01)
    assert mad_scale(r_abs, dof, 0.3) == pytest.approx(0.2, rel=0.01)
    assert mad_scale(np.zeros(0), dof) == 0.0


# ----------------------------------------------------------------------------- hypotheses

@pytest.mark.parametrize("dim", [2, 3])
def test_rotation_hypotheses_are_proper_and_within_the_limit(dim: int) -> None:
    rots = rotation_hypotheses(dim, 256, 90.0)
    np.testing.assert_allclose(rots[0], np.eye(dim))
    np.testing.assert_allclose(np.einsum("kij,kil->kjl", rots, rots), np.broadcast_to(np.eye(dim), rots.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rots), 1.0, atol=1e-12)
    cos = (np.trace(rots, axis1=1, axis2=2) - (dim - 2)) / 2 if dim == 3 else np.trace(rots, axis1=1, axis2=2) / 2
    assert np.rad2deg(np.arccos(np.clip(cos, -1, 1))).max() <= 90.0 + 1e-9
    assert len(rots) > (20 if dim == 3 else 100)
    np.testing.assert_array_equal(rots, rotation_hypotheses(dim, 256, 90.0))     # deterministic


# ----------------------------------------------------------------------------- registration

@pytest.mark.parametrize("variant", ["point_to_point", "point_to_plane"])
def test_recovers_a_large_rotation_with_the_global_start(variant: str) -> None:
    rng = np.random.default_rng(1)
    target = _surface(3000, rng)
    rot, shift = _rotation([1.0, 2.0, 0.5], 65.0), np.array([0.4, -0.3, 0.2])
    model = _moved(_surface(3000, rng), rot, shift)                    # other samples of the surface
    fit = icp_register(model, target, ICPOptions(variant=variant), np.random.default_rng(0))
    assert fit.matrix.shape == (3, 4)
    assert _angle_error(fit.matrix, rot) < 0.5
    np.testing.assert_allclose(fit.matrix[:, 3], shift, atol=0.02)
    assert 0 < fit.n_iter <= ICPOptions().max_iter
    assert fit.reach > 0


def test_plain_local_icp_fails_where_the_global_start_succeeds() -> None:
    rng = np.random.default_rng(2)
    target = _surface(1500, rng)
    rot = _rotation([0.0, 0.3, 1.0], 80.0)
    model = _moved(target, rot, np.zeros(3))
    local = icp_register(model, target, ICPOptions(init="given", loss="l2", variant="point_to_point"),
                         np.random.default_rng(0))
    searched = icp_register(model, target, ICPOptions(), np.random.default_rng(0))
    assert _angle_error(local.matrix, rot) > 10.0
    assert _angle_error(searched.matrix, rot) < 0.1


@pytest.mark.parametrize("loss", ["cauchy", "trimmed", "tukey", "welsch", "geman_mcclure", "huber", "student",
                                  "switchable", "max_distance", "l1"])
def test_robust_losses_resist_outliers(loss: str) -> None:
    rng = np.random.default_rng(3)
    target = _surface(1500, rng)
    rot, shift = _rotation([0.2, -1.0, 0.4], 10.0), np.array([0.1, 0.2, -0.1])
    model = _moved(target + rng.normal(scale=0.003, size=target.shape), rot, shift)
    bad = rng.choice(len(model), 300, replace=False)                   # 20 % gross outliers
    model[bad] = rng.uniform(model.min(0) - 0.5, model.max(0) + 0.5, size=(300, 3))
    fit = icp_register(model, target, ICPOptions(loss=loss, init="given"), np.random.default_rng(0))  # type: ignore[arg-type]
    assert _angle_error(fit.matrix, rot) < 0.5, loss
    np.testing.assert_allclose(fit.matrix[:, 3], shift, atol=0.02)


def test_l2_is_pulled_by_outliers() -> None:
    rng = np.random.default_rng(3)
    target = _surface(1500, rng)
    rot, shift = _rotation([0.2, -1.0, 0.4], 5.0), np.array([0.1, 0.2, -0.1])
    model = _moved(target, rot, shift)
    bad = rng.choice(len(model), 500, replace=False)
    model[bad] = rng.uniform(model.min(0) - 1.0, model.max(0) + 1.0, size=(500, 3)) + [0.0, 0.0, 1.0]
    l2 = icp_register(model, target, ICPOptions(loss="l2", init="given"), np.random.default_rng(0))
    cauchy = icp_register(model, target, ICPOptions(init="given"), np.random.default_rng(0))
    assert _angle_error(l2.matrix, rot) > 10 * max(_angle_error(cauchy.matrix, rot), 0.01)


def test_partial_overlap() -> None:
    rng = np.random.default_rng(4)
    pts = _surface(6000, rng)
    rot, shift = _rotation([1.0, 0.0, 1.0], 30.0), np.array([0.3, 0.0, 0.1])
    target = pts[pts[:, 0] > -0.5]                                      # 70 % overlap each
    model = _moved(pts[pts[:, 0] < 0.5], rot, shift)
    fit = icp_register(model, target, ICPOptions(loss="trimmed", trim_ratio=None), np.random.default_rng(0))
    assert _angle_error(fit.matrix, rot) < 1.0


def test_default_scale_survives_when_most_pairs_are_wrong() -> None:
    # 70 % of the model overlaps the target and half of the model is gross outliers: about 35 %
    # of the pairs are right, so the median residual (the plain MAD) lies among the wrong ones
    rng = np.random.default_rng(6)
    pts = _surface(6000, rng)
    rot, shift = _rotation([0.3, 1.0, -0.2], 3.0), np.array([0.05, -0.03, 0.02])
    target = pts[pts[:, 0] > -0.8]
    model = pts[pts[:, 0] < 0.8].copy()
    bad = rng.choice(len(model), len(model) // 2, replace=False)
    model[bad] = rng.uniform(model.min(0) - 0.5, model.max(0) + 0.5, size=(len(bad), 3))
    model = _moved(model + rng.normal(scale=0.003, size=model.shape), rot, shift)
    default = icp_register(model, target, ICPOptions(init="given"), np.random.default_rng(0))
    plain_mad = icp_register(model, target, ICPOptions(init="given", scale_quantile=0.5), np.random.default_rng(0))
    assert _angle_error(default.matrix, rot) < 0.2
    np.testing.assert_allclose(default.matrix[:, 3], shift, atol=0.005)
    assert _angle_error(plain_mad.matrix, rot) > 1.0                   # what the default is for


def test_coarse_stage_picks_the_best_of_the_search_candidates() -> None:
    # the search's winner is far off (a pose the search scored best), its runner-up is near the
    # truth: the coarse stage converges from both and keeps the one that fits
    rng = np.random.default_rng(8)
    target = _surface(4000, rng)
    rot, shift = _rotation([0.2, -1.0, 0.4], 8.0), np.array([0.1, 0.2, -0.1])
    model = _moved(target + rng.normal(scale=0.003, size=target.shape), rot, shift)
    flip = _rotation([1.0, 0.0, 0.0], 180.0) @ rot                     # the surface upside down
    wrong = np.c_[flip, target.mean(0) - flip @ model.mean(0)]
    near = np.c_[_rotation([0.2, -1.0, 0.4], 5.0), shift + 0.05]
    opts, tree = ICPOptions(), cKDTree(target)
    alone = refine_icp(model, target, tree, Start(wrong, np.inf), opts, np.random.default_rng(0))
    both = refine_icp(model, target, tree, Start(wrong, np.inf, (near,)), opts, np.random.default_rng(0))
    assert _angle_error(alone.matrix, rot) > 10.0                       # the winner alone stays wrong
    assert _angle_error(both.matrix, rot) < 0.2
    np.testing.assert_allclose(both.matrix[:, 3], shift, atol=0.01)


def test_coarse_stage_shortlist_keeps_the_start_that_fits_among_many_wrong_ones() -> None:
    # five starts, four of them wrong: each runs a few iterations, the best two go on, and the
    # one near the truth is among them wherever it stands in the list
    rng = np.random.default_rng(8)
    target = _surface(4000, rng)
    rot, shift = _rotation([0.2, -1.0, 0.4], 8.0), np.array([0.1, 0.2, -0.1])
    model = _moved(target + rng.normal(scale=0.003, size=target.shape), rot, shift)
    wrong = []
    for axis in ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]):
        turn = _rotation(axis, 150.0) @ rot
        wrong.append(np.c_[turn, target.mean(0) - turn @ model.mean(0)])
    near = np.c_[_rotation([0.2, -1.0, 0.4], 5.0), shift + 0.05]
    opts, tree = ICPOptions(), cKDTree(target)
    for place in (0, 2, 4):
        cands = [*wrong[:place], near, *wrong[place:]]
        fit = refine_icp(model, target, tree, Start(cands[0], np.inf, tuple(cands[1:])), opts,
                         np.random.default_rng(0))
        assert _angle_error(fit.matrix, rot) < 0.2, place
        np.testing.assert_allclose(fit.matrix[:, 3], shift, atol=0.01)


def test_outliers_through_the_volume_are_left_out_of_the_feature_start_and_the_icp() -> None:
    # half the model's points are uniform outliers in its bounding box: the feature start's
    # downsampling drops their cubes, the ICP iterates on the surface and finds the pose
    rng = np.random.default_rng(4)
    rot, shift = _rotation([0.3, 1.0, -0.5], 70.0), np.array([0.4, -0.2, 0.3])
    target = _surface(20000, rng) @ rot.T + shift
    clean = _surface(30000, rng) + rng.normal(scale=0.003, size=(30000, 3))
    # about 1.3 outliers a cube of the feature start (fewer, spread thinner, cannot be told apart)
    outliers = rng.uniform(clean.min(0), clean.max(0), size=(30000, 3))
    model = np.vstack([clean, outliers])
    start, evidence = feature_start(model, target, ICPOptions(), np.random.default_rng(0))
    assert start is not None and evidence is not None and evidence.surface is not None
    assert evidence.surface[:30000].mean() > 0.9 and evidence.surface[30000:].mean() < 0.3
    fit = icp_register(model, target, ICPOptions(), np.random.default_rng(0))
    assert fit.converged and fit.reason is None
    assert _angle_error(fit.matrix, rot) < 0.5
    np.testing.assert_allclose(fit.matrix[:, 3], shift, atol=0.02)


def test_refine_from_the_identity_is_icp_with_the_given_start() -> None:
    rng = np.random.default_rng(10)
    target = _surface(1500, rng)
    model = _moved(target, _rotation([1.0, 0.0, 0.2], 6.0), np.array([0.02, 0.0, 0.01]))
    opts = ICPOptions(init="given")
    given = icp_register(model, target, opts, np.random.default_rng(3))
    refined = refine_icp(model, target, cKDTree(target), Start(np.c_[np.eye(3), np.zeros(3)], np.inf), opts,
                         np.random.default_rng(3))
    np.testing.assert_array_equal(given.matrix, refined.matrix)
    assert (given.n_iter, given.converged, given.reach) == (refined.n_iter, refined.converged, refined.reach)


def test_given_normals_and_fa3r_give_the_same_answer() -> None:
    rng = np.random.default_rng(5)
    target = _surface(2000, rng)
    rot, shift = _rotation([0.0, 1.0, 1.0], 10.0), np.array([0.05, 0.0, 0.02])
    model = _moved(target, rot, shift)
    normals = estimate_normals(target, 10)
    a = icp_register(model, target, ICPOptions(init="given"), np.random.default_rng(0))
    b = icp_register(model, target, ICPOptions(init="given"), np.random.default_rng(0), target_normals=normals)
    np.testing.assert_allclose(a.matrix, b.matrix, atol=1e-9)
    svd = icp_register(model, target, ICPOptions(init="given", variant="point_to_point"), np.random.default_rng(0))
    fa3r = icp_register(model, target, ICPOptions(init="given", variant="point_to_point", solver="fa3r"),
                        np.random.default_rng(0))
    np.testing.assert_allclose(svd.matrix, fa3r.matrix, atol=1e-9)
    np.testing.assert_allclose(svd.matrix, np.c_[rot, shift], atol=1e-6)
    # model normals: pairs with incompatible normals are dropped, the answer stays right
    c = icp_register(model, target, ICPOptions(init="given"), np.random.default_rng(0),
                     model_normals=normals @ rot)
    np.testing.assert_allclose(c.matrix, np.c_[rot, shift], atol=1e-5)


@pytest.mark.parametrize("variant", ["point_to_point", "point_to_plane"])
def test_two_dimensional(variant: str) -> None:
    rng = np.random.default_rng(6)
    s = rng.uniform(0, 2 * np.pi, 400)
    target = np.c_[np.cos(s) * (1 + 0.3 * np.cos(3 * s)), 0.6 * np.sin(s) + 0.1 * np.cos(2 * s)]
    th = np.deg2rad(50.0)
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    model = (target - [0.2, -0.1]) @ rot
    fit = icp_register(model, target, ICPOptions(variant=variant), np.random.default_rng(0))  # type: ignore[arg-type]
    assert fit.matrix.shape == (2, 3)
    np.testing.assert_allclose(fit.matrix, np.c_[rot, [0.2, -0.1]], atol=1e-4)


def test_deterministic_given_the_seed() -> None:
    rng = np.random.default_rng(7)
    target = _surface(1500, rng)
    model = _moved(_surface(1500, rng), _rotation([1.0, 1.0, 0.0], 40.0), np.zeros(3))
    opts = ICPOptions(max_points=500)
    a = icp_register(model, target, opts, np.random.default_rng(11))
    b = icp_register(model, target, opts, np.random.default_rng(11))
    np.testing.assert_array_equal(a.matrix, b.matrix)


def test_errors() -> None:
    pts = _surface(50, np.random.default_rng(8))
    with pytest.raises(InputError, match=r"`solver`='fa3r' needs 3-D points"):
        icp_register(pts[:, :2], pts[:, :2], ICPOptions(solver="fa3r"), np.random.default_rng(0))
    with pytest.raises(InputError, match=r"`target_normals` must have shape \(50, 3\)"):
        icp_register(pts, pts, ICPOptions(), np.random.default_rng(0), target_normals=np.ones((49, 3)))


@pytest.mark.slow
def test_whole_kinect_sized_frame() -> None:
    """300k points each: the run stays within memory (no N x M matrix) and gets the motion."""
    rng = np.random.default_rng(9)
    u, v = np.meshgrid(np.linspace(-1.0, 1.0, 640), np.linspace(-0.75, 0.75, 480))
    z = 2.0 + 0.2 * np.sin(3 * u) * np.cos(2 * v) + 0.1 * u
    frame = np.dstack([u * z, v * z, z]).reshape(-1, 3)
    rot, shift = _rotation([0.3, 1.0, 0.1], 8.0), np.array([0.05, -0.02, 0.03])
    model = _moved(frame + rng.normal(scale=0.002, size=frame.shape), rot, shift)
    fit = icp_register(model, frame, ICPOptions(), np.random.default_rng(0))
    assert _angle_error(fit.matrix, rot) < 0.2


# ----------------------------------------------------------------------------- verify

def test_disagreement_of_a_pose_and_its_inverse_is_zero_and_measures_a_slide() -> None:
    from reglib.registration._icp import disagreement
    rng = np.random.default_rng(7)
    target = _surface(2000, rng)
    rot, shift = _rotation([0.3, 1.0, -0.2], 140.0), np.array([1.0, -2.0, 0.5])
    forward = np.c_[rot, shift]
    backward = np.c_[rot.T, -rot.T @ shift]
    assert disagreement(forward, backward, target) < 1e-12
    slid = backward.copy()
    slid[:, 3] += [0.06, 0.0, 0.0]  # the backward answer slid by 0.06 along x (in the model's frame)
    extent = float(np.linalg.norm(target.max(0) - target.min(0)))
    assert disagreement(forward, slid, target) == pytest.approx(0.06 / extent, rel=1e-9)


def _half_overlap_pair():
    """A bumpy surface cut into two parts sharing about half of each (the model moved by a large rotation)."""
    rng = np.random.default_rng(4)
    pts = _surface(8000, rng)
    rot, shift = _rotation([1.0, 2.0, 0.5], 65.0), np.array([0.4, -0.3, 0.2])
    target = pts[pts[:, 0] > -0.5]
    model = _moved(pts[pts[:, 0] < 0.5], rot, shift)
    return model, target, rot


def test_verify_keeps_a_consistent_answer_as_it_was() -> None:
    model, target, rot = _half_overlap_pair()
    plain = icp_register(model, target, ICPOptions(verify=False), np.random.default_rng(1))
    checked = icp_register(model, target, ICPOptions(verify=True), np.random.default_rng(1))
    np.testing.assert_array_equal(checked.matrix, plain.matrix)
    assert checked.converged and checked.reason is None
    assert _angle_error(checked.matrix, rot) < 1.0


def _counting_refine(monkeypatch: pytest.MonkeyPatch, slide: float, slid: tuple[int, ...]) -> list:
    """Make the refinements numbered ``slid`` (1: the forward run's; 2, 3: the backward runs') answer a pose slid
    by ``slide`` (and left there: no tight polish); count the calls."""
    import reglib.registration._icp as icp_module
    real = icp_module.refine_icp
    calls: list = []

    def refine(model_, target_, tree, start, opts, rng_, **kw):
        fit = real(model_, target_, tree, start, opts, rng_, **kw)
        calls.append(1)
        if len(calls) in slid:
            from dataclasses import replace
            matrix = fit.matrix.copy()
            matrix[:, 3] += slide
            fit = replace(fit, matrix=matrix)
        return fit

    monkeypatch.setattr(icp_module, "refine_icp", refine)
    # the tight polish after the refinement would bring a slide this small back: these tests are of the reverse check
    monkeypatch.setattr(icp_module, "tight_polish", lambda model_, tree, matrix, normals=None: (matrix, False))
    return calls


def test_verify_says_a_disagreement(monkeypatch: pytest.MonkeyPatch) -> None:
    # every backward run is made to answer a pose 0.3 off (as a slide on a partial scan would): the forward answer,
    # right as it is, is then not supported by its reverse; the slid backward run says it is unsupported itself, so
    # it gets its second try, which disagrees too
    model, target, rot = _half_overlap_pair()
    calls = _counting_refine(monkeypatch, 0.3, (2, 3))
    fit = icp_register(model, target, ICPOptions(), np.random.default_rng(1))
    assert len(calls) == 3
    assert not fit.converged and fit.reason == "inconsistent"
    assert _angle_error(fit.matrix, rot) < 1.0  # the answer itself is still given


def test_verify_gives_an_unsupported_backward_run_a_second_try(monkeypatch: pytest.MonkeyPatch) -> None:
    model, target, rot = _half_overlap_pair()
    calls = _counting_refine(monkeypatch, 0.3, (2,))
    fit = icp_register(model, target, ICPOptions(), np.random.default_rng(1))
    assert len(calls) == 3
    assert fit.converged and fit.reason is None


def test_verify_does_not_run_at_full_overlap(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(1)
    target = _surface(3000, rng)
    rot, shift = _rotation([1.0, 2.0, 0.5], 65.0), np.array([0.4, -0.3, 0.2])
    model = _moved(_surface(3000, rng), rot, shift)
    calls = _counting_refine(monkeypatch, 0.3, (2, 3))
    fit = icp_register(model, target, ICPOptions(), np.random.default_rng(0))
    assert len(calls) == 1 and fit.converged


def test_a_capped_answer_that_the_tight_polish_settles_is_converged(monkeypatch: pytest.MonkeyPatch) -> None:
    # the refinement is made to stop short (slid, its cap reached): the polish brings the pose back and settles
    # there, so the answer given is settled; without the polish it is not
    from dataclasses import replace

    import reglib.registration._icp as icp_module
    model, target, rot = _half_overlap_pair()
    truth = icp_register(model, target, ICPOptions(verify=False), np.random.default_rng(1)).matrix
    real = icp_module.refine_icp

    def refine(*args, **kw):
        fit = real(*args, **kw)
        matrix = fit.matrix.copy()
        matrix[:, 3] += 0.1
        return replace(fit, matrix=matrix, converged=False)

    monkeypatch.setattr(icp_module, "refine_icp", refine)
    fit = icp_register(model, target, ICPOptions(verify=False), np.random.default_rng(1))
    assert fit.converged and fit.reason is None
    assert np.abs(fit.matrix - truth).max() < 0.01
    monkeypatch.setattr(icp_module, "tight_polish", lambda model_, tree, matrix, normals=None: (matrix, False))
    assert not icp_register(model, target, ICPOptions(verify=False), np.random.default_rng(1)).converged
