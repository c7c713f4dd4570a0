import copy
import json

import numpy as np
import pytest

from reglib import InputError, KernelWarp
from reglib._transforms import LinearPart, kernel_apply, kernel_matrix


def sample_warp(linear="affine", dim=2, m=6, seed=0):
    rng = np.random.default_rng(seed)
    lin = None
    if linear == "affine":
        lin = LinearPart("affine", np.c_[np.eye(dim) + 0.1 * rng.normal(size=(dim, dim)), rng.normal(size=dim)])
    elif linear == "homography":
        h = np.eye(3) + 0.05 * rng.normal(size=(3, 3))
        lin = LinearPart("homography", h / h[2, 2])
    return KernelWarp(dim=dim, src_mean=rng.normal(size=dim) * 100, src_scale=150.0,
                      dst_mean=rng.normal(size=dim) * 100,
                      dst_scale=170.0, linear=lin, beta=1.3, centers=rng.normal(size=(m, dim)),
                      weights=0.2 * rng.normal(size=(m, dim)))


def formula(d, pts):
    """CONTRACTS.md's formula, written out directly."""
    u = (pts - np.asarray(d["src_mean"])) / d["src_scale"]
    lin = d["linear"]
    if lin is None:
        g = u
    elif lin["kind"] == "affine":
        a = np.asarray(lin["matrix"])
        g = u @ a[:, :-1].T + a[:, -1]
    else:
        h = np.asarray(lin["matrix"])
        q = np.c_[u, np.ones(len(u))] @ h.T
        g = q[:, :2] / q[:, 2:]
    c, w = np.asarray(d["centers"]), np.asarray(d["weights"])
    k = np.exp(-d["beta"] * ((u[:, None, :] - c[None]) ** 2).sum(-1))
    return np.asarray(d["dst_mean"]) + d["dst_scale"] * (g + k @ w)


@pytest.mark.parametrize("linear, dim", [("affine", 2), ("none", 2), ("homography", 2), ("affine", 3), ("none", 3)])
def test_matches_contract_formula_and_round_trips(linear, dim):
    warp = sample_warp(linear, dim)
    d = json.loads(json.dumps(warp.to_dict()))
    assert d["type"] == "kernel_warp" and d["version"] == 1 and d["dim"] == dim
    pts = np.random.default_rng(1).uniform(-300, 300, (40, dim))
    np.testing.assert_allclose(warp(pts), formula(d, pts), rtol=1e-12, atol=1e-9)
    back = KernelWarp.from_dict(d)
    np.testing.assert_array_equal(back(pts), warp(pts))
    assert back.to_dict() == d


@pytest.mark.parametrize("linear", ["affine", "none", "homography"])
def test_jacobian_matches_finite_differences(linear):
    warp = sample_warp(linear)
    pts = np.random.default_rng(2).uniform(-200, 200, (25, 2))
    eps = 1e-4
    numeric = np.stack([(warp(pts + eps * e) - warp(pts - eps * e)) / (2 * eps) for e in np.eye(2)], axis=-1)
    np.testing.assert_allclose(warp.jacobian(pts), numeric, rtol=1e-5, atol=1e-6)


def test_identity_and_empty_points():
    ident = KernelWarp.identity(3)
    pts = np.arange(12.0).reshape(4, 3)
    np.testing.assert_array_equal(ident(pts), pts)
    assert ident(np.zeros((0, 3))).shape == (0, 3)
    assert KernelWarp.identity(2).jacobian([[1.0, 2.0]]).tolist() == [[[1.0, 0.0], [0.0, 1.0]]]
    with pytest.raises(InputError, match="`dim` must be 2 or 3"):
        KernelWarp.identity(4)


def test_many_points_evaluated_in_blocks():
    warp = sample_warp("affine", m=50)
    pts = np.random.default_rng(3).uniform(-100, 100, (100_000, 2))
    out = warp(pts)
    np.testing.assert_allclose(out[-5:], warp(pts[-5:]), rtol=0, atol=1e-9)


def test_value_is_immutable():
    warp = sample_warp()
    with pytest.raises(ValueError):
        warp.centers[0, 0] = 1.0
    with pytest.raises(AttributeError):
        warp.beta = 2.0  # type: ignore[misc]


def test_wrong_dimension_points_named():
    with pytest.raises(InputError, match=r"`points` must have shape \(N, 2\)"):
        sample_warp()(np.zeros((3, 3)))


@pytest.mark.parametrize(
    "change, pattern",
    [
        (lambda d: d.pop("beta"), r"missing field\(s\) \['beta'\]"),
        (lambda d: d.update(type="tps"), r"`type` must be 'kernel_warp'"),
        (lambda d: d.update(version=2), r"`version` must be 1"),
        (lambda d: d.update(dim=4), r"`dim` must be 2 or 3"),
        (lambda d: d.update(src_mean=[0.0]), r"`src_mean` must have 2 numbers"),
        (lambda d: d.update(src_scale=0.0), r"`src_scale` must be a positive finite number"),
        (lambda d: d.update(dst_scale=float("nan")), r"`dst_scale` must be a positive finite number"),
        (lambda d: d.update(beta="wide"), r"`beta` must be a positive finite number"),
        (lambda d: d.update(centers=[[0.0, 1.0, 2.0]]), r"`centers` must have shape \(M, 2\)"),
        (lambda d: d.update(weights=d["weights"][:-1]), r"`weights` must have the shape of `centers`"),
        (lambda d: d.update(weights=[[float("inf"), 0.0]] * len(d["centers"])), r"`weights` must hold only finite"),
        (lambda d: d.update(linear={"kind": "spline"}), r"`linear` must be null or"),
        (lambda d: d.update(linear={"kind": "affine", "matrix": [[1.0, 0.0], [0.0, 1.0]]}),
         r"`linear.matrix` must have shape \(2, 3\)"),
        (lambda d: d.update(centers="abc"), r"`centers` must be numbers"),
    ],
)
def test_from_dict_rejects_malformed_fields(change, pattern):
    d = copy.deepcopy(sample_warp().to_dict())
    change(d)
    with pytest.raises(InputError, match=pattern):
        KernelWarp.from_dict(d)


def test_from_dict_rejects_non_object_and_3d_homography():
    with pytest.raises(InputError, match="JSON object"):
        KernelWarp.from_dict([1, 2])
    d = sample_warp("affine", dim=3).to_dict()
    d["linear"] = {"kind": "homography", "matrix": np.eye(3).tolist()}
    with pytest.raises(InputError, match="needs dim 2"):
        KernelWarp.from_dict(d)


@pytest.mark.parametrize("dim", [2, 3])
def test_single_precision_exp_is_within_2e_7_of_the_exact_kernel(dim):
    """The estimators' float32 exp: each kernel value (in [0, 1]) within 2e-7 of the exact one (the
    rounding of the exponent, |x| e^x 6e-8, and float32 exp's own, 1-2 ulp); fields alike."""
    rng = np.random.default_rng(3)
    pts, centers = rng.normal(size=(3000, dim)) * 2.0, rng.normal(size=(40, dim))
    exact = np.exp(-4.0 * ((pts[:, None, :] - centers[None]) ** 2).sum(-1))
    fast = kernel_matrix(pts, centers, 4.0, single_exp=True)
    assert fast.dtype == np.float64 and fast.shape == exact.shape
    assert np.abs(fast - exact).max() <= 2e-7
    assert np.abs(fast - exact).max() > 0  # (it is not the float64 kernel)
    weights = rng.normal(size=(40, dim))
    field = kernel_apply(pts, centers, 4.0, weights, np.zeros((3000, dim)), single_exp=True)
    bound = 2e-7 * np.abs(weights).sum(0)
    assert np.all(np.abs(field - exact @ weights) <= bound)
    # a transform is evaluated in float64 throughout (the exact JSON formula holds to rounding)
    exact_field = kernel_apply(pts, centers, 4.0, weights, np.zeros((3000, dim)))
    np.testing.assert_allclose(exact_field, exact @ weights, rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("empty", [[], [[]]])
def test_from_dict_reads_empty_centres_as_no_kernel(dim, empty):
    d = sample_warp("none", dim=dim).to_dict()
    d.update(centers=empty, weights=empty)
    back = KernelWarp.from_dict(d)
    assert back.centers.shape == back.weights.shape == (0, dim) and back.n_centers == 0
    pts = np.random.default_rng(4).uniform(-50, 50, (10, dim))
    want = np.asarray(d["dst_mean"]) + d["dst_scale"] * (pts - np.asarray(d["src_mean"])) / d["src_scale"]
    np.testing.assert_allclose(back(pts), want, rtol=1e-12)


@pytest.mark.parametrize(
    "change, pattern",
    [
        (lambda d: d.update(version=True), r"`version` must be 1, got True"),
        (lambda d: d.update(version="1"), r"`version` must be 1, got '1'"),
        (lambda d: d.update(dim=True), r"`dim` must be 2 or 3, got True"),
        (lambda d: d.update(beta=True), r"`beta` must be a positive finite number, got True"),
        (lambda d: d.update(src_scale=float("inf")), r"`src_scale` must be a positive finite number, got inf"),
        (lambda d: d.update(dst_mean=[0.0, float("nan")]), r"`dst_mean` must hold only finite numbers"),
        (lambda d: d.update(dst_mean=[[0.0, 1.0]]), r"`dst_mean` must have 2 numbers, got shape \(1, 2\)"),
        (lambda d: d.update(centers=[1.0, 2.0]), r"`centers` must have shape \(M, 2\), got \(2,\)"),
        (lambda d: d.update(centers=[], weights=[[0.0, 1.0]]),
         r"`weights` must have the shape of `centers` \(0, 2\), got \(1, 2\)"),
        (lambda d: d.update(linear=[1, 2]), r"`linear` must be null or \{'kind'"),
        (lambda d: d.update(linear={"kind": "affine"}), r"`linear.matrix` must hold only finite numbers"),
        (lambda d: d.update(linear={"kind": "affine", "matrix": "m"}), r"`linear.matrix` must be numbers"),
        (lambda d: d.update(linear={"kind": "homography", "matrix": np.eye(2).tolist()}),
         r"`linear.matrix` must have shape \(3, 3\), got \(2, 2\)"),
        # several bad fields: the checks run in one order (type, version, dim, centres, weights, linear, the rest)
        (lambda d: d.update(type="x", version=2), r"`type` must be 'kernel_warp'"),
        (lambda d: d.update(dim=4, centers="abc"), r"`dim` must be 2 or 3"),
        (lambda d: d.update(weights="abc", linear=[1]), r"`weights` must be numbers"),
        (lambda d: d.update(linear=[1], src_mean=[0.0], beta=0), r"`linear` must be null or"),
        (lambda d: d.update(src_mean=[0.0], src_scale=0, beta=0), r"`src_mean` must have 2 numbers"),
        (lambda d: d.update(src_scale=0, dst_mean=[0.0], beta=0), r"`src_scale` must be a positive"),
        (lambda d: d.update(dst_mean=[0.0], dst_scale=0, beta=0), r"`dst_mean` must have 2 numbers"),
        (lambda d: d.update(dst_scale=0, beta=0), r"`dst_scale` must be a positive"),
        (lambda d: (d.pop("weights"), d.pop("beta")), r"missing field\(s\) \['beta', 'weights'\]"),
    ],
)
def test_from_dict_names_the_first_malformed_field(change, pattern):
    d = copy.deepcopy(sample_warp().to_dict())
    change(d)
    with pytest.raises(InputError, match=pattern):
        KernelWarp.from_dict(d)
