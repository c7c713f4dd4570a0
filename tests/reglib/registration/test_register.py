"""Tests of reglib.register_points: ground truth made by warping point sets with known maps.

The contract every method keeps (result shapes and fields, its JSON form, its input errors) is
in test_methods.py; here are the behaviours of the non-rigid and CPD methods, and PointCloud
values in place of arrays and keyword colors / normals.
"""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from reglib import CPDOptions, InputError, Registration, RegistrationOptions, register_points
from reglib.io import PointCloud
from reglib.registration._normals import estimate_normals


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


@pytest.mark.parametrize("method", ["icp", "cpd-rigid", "cpd-affine"])
def test_a_3d_rotation_and_shift_come_back_as_a_4x4_matrix(method):
    rng = np.random.default_rng(4)
    model = rng.normal(size=(200, 3)) * [3.0, 2.0, 1.0]  # distinct axes: one right rotation
    rot = Rotation.from_euler("xyz", [20.0, -15.0, 30.0], degrees=True).as_matrix()
    shift = np.array([25.0, -12.0, 7.5])  # far from the origin: the translation CPD used to keep in its means
    res = register_points(model, model @ rot.T + shift, method=method, rng=0)
    m = res.matrix
    assert m.shape == (4, 4) and np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(model @ m[:3, :3].T + m[:3, 3], res.registered, rtol=0, atol=1e-6)
    np.testing.assert_allclose(m[:3, :3], rot, atol=1e-6)
    np.testing.assert_allclose(m[:3, 3], shift, atol=1e-5)
    body = res.to_dict()
    t = body["transform"]
    assert t["src_mean"] == t["dst_mean"] == [0.0, 0.0, 0.0] and t["src_scale"] == t["dst_scale"] == 1.0
    np.testing.assert_array_equal(t["linear"]["matrix"], m[:3])
    np.testing.assert_array_equal(body["matrix"], m)


def test_a_2d_linear_map_is_a_3x3_matrix_and_a_non_rigid_one_has_none():
    model = _contour()
    a = np.array([[1.2, 0.3], [-0.1, 0.8]])
    res = register_points(model, model @ a.T + [-2.0, 0.5], method="cpd-affine", rng=0)
    np.testing.assert_allclose(res.matrix, [[1.2, 0.3, -2.0], [-0.1, 0.8, 0.5], [0.0, 0.0, 1.0]], atol=1e-4)
    bent = register_points(model, _bend(model), method="cpd", rng=0)
    assert bent.matrix is None and bent.to_dict()["matrix"] is None
    assert Registration.from_dict(bent.to_dict()).matrix is None


def test_a_matrix_read_back_is_checked():
    body = register_points(_contour(), _contour() + 1.0, method="cpd-rigid", rng=0).to_dict()
    assert Registration.from_dict({k: v for k, v in body.items() if k != "matrix"}).matrix is None  # optional
    with pytest.raises(InputError, match=r"registration `matrix` must have shape \(3, 3\), got \(2, 3\)"):
        Registration.from_dict({**body, "matrix": body["matrix"][:2]})
    with pytest.raises(InputError, match=r"`matrix` must be homogeneous, its last row \(0, ..., 0, 1\)"):
        Registration.from_dict({**body, "matrix": body["matrix"][:2] + [[0.0, 1.0, 1.0]]})


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


# PointCloud values: what is read from them is what the keywords would give


def _same(a, b):
    return json.dumps(a.to_dict()) == json.dumps(b.to_dict())


def _motion3(degrees=12.0):
    """A known rigid motion (scipy's rotation, independent of the library)."""
    return Rotation.from_rotvec(np.deg2rad(degrees) * np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)).as_matrix(), \
        np.array([0.2, -0.1, 0.3])


def _colored_surface(n=400, seed=0):
    """Points on z = f(x, y), their RGB in [0, 1] and their exact unit normals."""
    xy = np.random.default_rng(seed).uniform(-1, 1, (n, 2))
    x, y = xy.T
    pts = np.c_[xy, 0.3 * np.sin(2 * x) * np.cos(3 * y) + 0.2 * x ** 2]
    colors = np.c_[0.5 + 0.4 * np.sin(3 * x), 0.5 + 0.4 * np.cos(2 * y), np.full(n, 0.3)]
    grad = np.c_[0.6 * np.cos(2 * x) * np.cos(3 * y) + 0.4 * x, -0.9 * np.sin(2 * x) * np.sin(3 * y)]
    normals = np.c_[-grad, np.ones(n)]
    return pts, colors, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def test_color_gmm_takes_point_clouds_as_it_takes_keyword_colors():
    p, c, _ = _colored_surface()
    rot, trans = _motion3()
    q = p @ rot.T + trans
    clouds = register_points(PointCloud(points=p, colors=c), PointCloud(points=q, colors=c), method="color-gmm", rng=0)
    keywords = register_points(p, q, method="color-gmm", rng=0, model_colors=c, target_colors=c)
    assert _same(clouds, keywords)
    assert np.abs(clouds.registered - q).max() < 0.01  # the surface spans 2
    mixed = register_points(PointCloud(points=p, colors=c), q, method="color-gmm", rng=0, target_colors=c)
    assert _same(mixed, keywords)


def test_color_gmm_in_2d_takes_a_color_per_point():
    xy, c, _ = _colored_surface(600, seed=3)
    xy = xy[:, :2]
    a = np.deg2rad(15.0)
    q = xy @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T + [2.0, 1.0]
    res = register_points(PointCloud(points=xy, colors=c), PointCloud(points=q, colors=c), method="color-gmm",
                          rng=0)
    assert np.abs(res.registered - q).max() < 0.02


def test_a_keyword_and_a_cloud_giving_the_same_extra_are_an_input_error():
    p, c, n = _colored_surface(100)
    with pytest.raises(InputError, match=r"`model_colors` and `model.colors` \(the PointCloud's\) are both given"):
        register_points(PointCloud(points=p, colors=c), p, method="color-gmm", model_colors=c, target_colors=c)
    with pytest.raises(InputError, match=r"`target_normals` and `target.normals` \(the PointCloud's\)"):
        register_points(p, PointCloud(points=p, normals=n), method="icp", target_normals=n)
    with pytest.raises(InputError, match=r"`model_colors` and `model.colors`"):  # whether the method uses them or not
        register_points(PointCloud(points=p, colors=c), p, method="cpd", model_colors=c)


def test_what_a_cloud_carries_is_checked_where_it_is_used_and_otherwise_not_read():
    p, c, n = _colored_surface(200)
    with pytest.raises(InputError, match=r"`model.colors` must have the shape of its points, \(200, 3\)"):
        register_points(PointCloud(points=p, colors=c[:-1]), PointCloud(points=p, colors=c), method="color-gmm")
    with pytest.raises(InputError, match=r"`target.colors` must be RGB values in \[0, 1\]"):
        register_points(PointCloud(points=p, colors=c), PointCloud(points=p, colors=2 * c), method="color-gmm")
    with pytest.raises(InputError, match=r"needs `target_colors` .*or a PointCloud `target` with colors"):
        register_points(PointCloud(points=p, colors=c), PointCloud(points=p), method="color-gmm")
    with pytest.raises(InputError, match=r"`model.points` must have shape \(N, 2\) or \(N, 3\)"):
        register_points(PointCloud(points=np.zeros((10, 4))), p)
    rot, trans = _motion3()
    q = p @ rot.T + trans
    junk = PointCloud(points=p, colors=c[:-1], normals=n[:5])  # misshaped, but cpd-rigid reads neither
    plain = register_points(p, q, method="cpd-rigid", rng=0)
    assert _same(register_points(junk, q, method="cpd-rigid", rng=0), plain)
    assert np.abs(plain.registered - q).max() < 1e-3


def test_icp_reads_a_clouds_normals_as_it_reads_keyword_normals():
    p, _, n = _colored_surface(600)
    rot, trans = _motion3()
    q, nq = p @ rot.T + trans, n @ rot.T
    opts = {"init": "given"}
    clouds = register_points(PointCloud(points=p, normals=n), PointCloud(points=q, normals=nq), method="icp",
                             options=opts, rng=0)
    keywords = register_points(p, q, method="icp", options=opts, rng=0, model_normals=n, target_normals=nq)
    assert _same(clouds, keywords)
    assert np.abs(clouds.registered - q).max() < 1e-4
    # read, not dropped: model normals along the surface disagree with every target normal, and leave
    # the model where it was
    along = np.c_[n[:, 2], np.zeros(len(n)), -n[:, 0]]
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    tangent = register_points(PointCloud(points=p, normals=along), PointCloud(points=q, normals=nq), method="icp",
                              options=opts, rng=0)
    assert np.abs(tangent.registered - q).max() > 0.1


def test_icp_point_to_point_leaves_target_normals_alone_only_when_a_cloud_carries_them():
    p, _, n = _colored_surface(300)
    rot, trans = _motion3()
    q, nq = p @ rot.T + trans, n @ rot.T
    opts = {"init": "given", "variant": "point_to_point"}
    plain = register_points(p, q, method="icp", options=opts, rng=0)
    assert np.abs(plain.registered - q).max() < 1e-4
    assert _same(register_points(p, PointCloud(points=q, normals=nq), method="icp", options=opts, rng=0), plain)
    with pytest.raises(InputError, match=r"`target_normals` is not used by method 'icp' with "
                                         r"variant='point_to_point' unless `model_normals` are given too"):
        register_points(p, q, method="icp", options=opts, rng=0, target_normals=nq)
    both = register_points(p, q, method="icp", options=opts, rng=0, model_normals=n, target_normals=nq)
    assert np.abs(both.registered - q).max() < 1e-4  # beside model normals they serve the angle check


def _organized_pair():
    """A 30 x 40 scan with unseen pixels, the target its seen points moved, and the target's normals."""
    yy, xx = np.mgrid[0:30, 0:40] / 30.0
    scan = np.dstack([xx, yy, 0.1 * np.sin(3 * xx) * np.cos(2 * yy) + 1.0])
    scan[0, :5] = np.nan
    rot, trans = _motion3(8.0)
    truth = scan.reshape(-1, 3) @ rot.T + trans
    target = truth[np.isfinite(truth).all(1)]
    return scan, target, truth, estimate_normals(target)


def test_icp_hmrf_takes_an_organized_cloud_and_the_targets_normals():
    scan, target, truth, tn = _organized_pair()
    arrays = register_points(scan, target, method="icp-hmrf", rng=0, target_normals=tn)
    seen = np.isfinite(truth).all(1)
    assert arrays.registered.shape == (1200, 3) and np.isnan(arrays.registered[~seen]).all()
    assert np.abs(arrays.registered[seen] - truth[seen]).max() < 0.01
    # the grid travels in the cloud; the model's normals it carries are not read (the field takes none)
    grid_normals = np.broadcast_to([0.0, 0.0, 1.0], scan.shape)
    clouds = register_points(PointCloud(points=scan, normals=grid_normals), PointCloud(points=target, normals=tn),
                             method="icp-hmrf", rng=0)
    assert _same(clouds, arrays)
    with pytest.raises(InputError, match=r"`model_normals` is used by method\(s\) \['icp'\] only, not by 'icp-hmrf'"):
        register_points(scan, target, method="icp-hmrf", model_normals=grid_normals)
    with pytest.raises(InputError, match=r"organized model scan of shape \(H, W, 3\), got \(1195, 3\)"):
        register_points(PointCloud(points=scan.reshape(-1, 3)[np.isfinite(scan.reshape(-1, 3)).all(1)]), target,
                        method="icp-hmrf")


def test_icp_hmrf_without_a_plane_step_leaves_target_normals_alone_only_when_a_cloud_carries_them():
    scan, target, _, tn = _organized_pair()
    opts = {"variant": "point_to_point", "prealign": False}
    plain = register_points(scan, target, method="icp-hmrf", options=opts, rng=0)
    assert _same(register_points(scan, PointCloud(points=target, normals=tn), method="icp-hmrf", options=opts,
                                 rng=0), plain)
    with pytest.raises(InputError, match=r"`target_normals` is not used by method 'icp-hmrf' with "
                                         r"variant='point_to_point' and prealign=False"):
        register_points(scan, target, method="icp-hmrf", options=opts, target_normals=tn)


@pytest.mark.parametrize("method", ["cpd-rigid", "icp", "cpd", "l2e"])
def test_fitness_and_inlier_rmse_are_measured_on_every_registration(method):
    """An exact rigid motion: every model point lands on its target (fitness 1, RMS near 0)."""
    rng = np.random.default_rng(4)
    model = rng.uniform(-1, 1, (300, 3))
    rot = Rotation.from_euler("z", 20, degrees=True).as_matrix()
    target = model @ rot.T + [0.1, -0.05, 0.02]
    reg = register_points(model, target, method=method, rng=0)
    assert reg.fitness == 1.0 and reg.inlier_rmse < 0.02
    body = json.loads(json.dumps(reg.to_dict()))
    assert body["fitness"] == reg.fitness and body["inlier_rmse"] == reg.inlier_rmse
    back = type(reg).from_dict(body)
    assert (back.fitness, back.inlier_rmse) == (reg.fitness, reg.inlier_rmse)
    with pytest.raises(InputError, match="`fitness` must be in"):
        type(reg).from_dict({**body, "fitness": 1.5})


def test_fitness_is_the_share_of_the_model_with_a_target_point_near():
    """30 of 330 model points far from everything: 300 / 330 are fitted, and they land on their targets."""
    rng = np.random.default_rng(4)
    model = rng.uniform(-1, 1, (300, 3))
    target = model + [0.1, -0.05, 0.02]
    reg = register_points(np.vstack([model, rng.uniform(20, 30, (30, 3))]), target, method="icp", rng=0)
    assert reg.fitness == pytest.approx(300 / 330) and reg.inlier_rmse < 1e-6


def test_the_registered_cloud_keeps_colours_and_turns_normals_as_normals_go():
    rng = np.random.default_rng(6)
    model = rng.normal(size=(120, 3)) * [2.0, 1.5, 1.0]
    a = np.array([[1.3, 0.2, 0.0], [-0.1, 0.9, 0.3], [0.0, 0.1, 1.1]])  # not orthogonal: normals are not A n
    normals = rng.normal(size=(120, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    colors = rng.random((120, 3))
    cloud = PointCloud(points=model, colors=colors, normals=normals)
    res = register_points(model, model @ a.T + [1.0, 2.0, 3.0], method="cpd-affine", rng=0)
    moved = res.registered_cloud(cloud)
    assert np.array_equal(moved.points, res.registered) and moved.colors is colors
    want = normals @ np.linalg.inv(a)  # rows of inv(A).T n
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(moved.normals, want, atol=1e-6)
    tangent = np.cross(normals, [0.0, 0.0, 1.0])  # perpendicular to each normal: stays so once moved
    np.testing.assert_allclose(np.einsum("ij,ij->i", tangent @ a.T, moved.normals), 0.0, atol=1e-6)
    with pytest.raises(InputError, match=r"`model` has points of shape \(119, 3\); this registration moved 120"):
        res.registered_cloud(PointCloud(points=model[:-1]))
    with pytest.raises(InputError, match=r"`model.normals` must have the shape of its points"):
        res.registered_cloud(PointCloud(points=model, normals=normals[:, :2]))


def test_an_organized_models_registered_cloud_is_its_grid_with_the_holes():
    yy, xx = np.mgrid[0:12, 0:15] / 12.0
    scan = np.dstack([xx, yy, 0.1 * np.sin(3 * xx) * np.cos(2 * yy)])
    scan[0, :3] = np.nan
    grid_normals = np.broadcast_to([0.0, 0.0, 1.0], scan.shape).copy()
    target = scan.reshape(-1, 3)[np.isfinite(scan.reshape(-1, 3)).all(1)] + [0.05, 0.0, 0.0]
    res = register_points(scan, target, method="icp", options={"init": "given"}, rng=0)
    moved = res.registered_cloud(PointCloud(points=scan, normals=grid_normals))
    assert moved.organized and moved.points.shape == scan.shape
    assert np.isnan(moved.points[0, :3]).all() and np.isnan(moved.normals[0, :3]).all()
    np.testing.assert_allclose(moved.points[1:], scan[1:] + [0.05, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(moved.normals[1:], grid_normals[1:], atol=1e-6)
