"""Tests of reglib.dense._flow: flow accuracy against exact evaluation, folds, warps, sample positions."""
from __future__ import annotations

import numpy as np
import pytest
import skimage.data

from reglib import KernelWarp, dense_flow, fold_fraction, warp_image
from reglib._transforms import LinearPart
from reglib.dense import remap_image
from reglib.dense._flow import remap_planes, sample_positions
from reglib.errors import InputError


def _bendy_warp(seed: int = 0, n: int = 40, beta: float = 8.0, amp: float = 0.05) -> KernelWarp:
    """A non-rigid warp on an 800 x 600 image: rotation + scale + narrow Gaussian bumps (~20 px)."""
    rng = np.random.default_rng(seed)
    ang = np.deg2rad(10.0)
    a = 1.1 * np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    lin = LinearPart(kind="affine", matrix=np.c_[a, [0.05, -0.02]])
    return KernelWarp(dim=2, src_mean=np.array([400.0, 300.0]), src_scale=300.0, dst_mean=np.array([410.0, 290.0]),
                      dst_scale=300.0, linear=lin, beta=beta, centers=rng.uniform(-1.4, 1.4, (n, 2)),
                      weights=rng.normal(0, amp, (n, 2)))


def _exact_flow(t: KernelWarp, h: int, w: int) -> np.ndarray:
    ys, xs = np.mgrid[0:h, 0:w]
    p = np.c_[xs.ravel(), ys.ravel()].astype(float)
    return (t(p) - p).reshape(h, w, 2)


@pytest.mark.parametrize("seed,beta,amp", [(0, 8.0, 0.05), (1, 30.0, 0.05), (2, 1.8, 0.4), (3, 0.5, 1.0)])
def test_dense_flow_within_005_px_of_exact_evaluation(seed, beta, amp):
    # (the node spacing tried first is predicted from the kernel's width and the weights; wide
    # kernels with large weights, the dense stage's final fields, as well as narrow ones)
    t = _bendy_warp(seed, beta=beta, amp=amp)
    h, w = 600, 800
    exact = _exact_flow(t, h, w)
    assert np.abs(exact).max() > 20  # the motion is substantial
    flow = dense_flow(t, (h, w))
    assert flow.shape == (h, w, 2) and flow.dtype == np.float32
    assert np.abs(flow - exact).max() <= 0.05


def test_dense_flow_is_forward_and_accepts_dicts_and_image_shapes():
    t = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.array([3.0, -2.0]), dst_scale=1.0,
                   linear=None, beta=1.0, centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    flow = dense_flow(t.to_dict(), (5, 7, 3))
    assert flow.shape == (5, 7, 2)
    assert np.allclose(flow[..., 0], 3.0) and np.allclose(flow[..., 1], -2.0)
    assert dense_flow(KernelWarp.identity(2), (1, 1)).shape == (1, 1, 2)


@pytest.mark.parametrize("shape,words", [((0, 5), "positive"), ((5,), "two integers"), (5, "tuple"),
                                         ((2.5, 3), "two integers")])
def test_dense_flow_bad_shape(shape, words):
    with pytest.raises(InputError, match=words):
        dense_flow(KernelWarp.identity(2), shape)


def test_dense_flow_bad_transform():
    with pytest.raises(InputError, match="transform"):
        dense_flow("not a transform", (3, 3))
    with pytest.raises(InputError, match="2-D"):
        dense_flow(KernelWarp.identity(3), (3, 3))


def test_fold_fraction():
    assert fold_fraction(KernelWarp.identity(2), (50, 60)) == 0.0
    mirror = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.zeros(2), dst_scale=1.0,
                        linear=LinearPart("affine", np.array([[-1.0, 0, 0], [0, 1.0, 0]])), beta=1.0,
                        centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    assert fold_fraction(mirror, (50, 60)) == 1.0
    # one strong bump pushing x backwards: folds near its centre only
    bump = KernelWarp(dim=2, src_mean=np.array([50.0, 50.0]), src_scale=50.0, dst_mean=np.array([50.0, 50.0]),
                      dst_scale=50.0, linear=None, beta=20.0, centers=np.zeros((1, 2)),
                      weights=np.array([[-0.6, 0.0]]))
    frac = fold_fraction(bump, (100, 100))
    ys, xs = np.mgrid[0:100, 0:100]
    jac = bump.jacobian(np.c_[xs.ravel(), ys.ravel()].astype(float))
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    truth = np.mean(det <= 0)
    assert 0.0 < truth < 0.5
    assert abs(frac - truth) < 0.01


def _shift(dx: float, dy: float) -> KernelWarp:
    return KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.array([dx, dy]), dst_scale=1.0,
                      linear=None, beta=1.0, centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))


def test_warp_image_samples_b_at_f_of_p():
    b = skimage.data.camera()
    warped, valid = warp_image(b, _shift(5, 3), b.shape)
    assert warped.dtype == np.uint8 and warped.shape == b.shape
    assert np.array_equal(warped[:-3, :-5], b[3:, 5:])  # out[p] = b(p + (5, 3))
    assert valid[:-3, :-5].all() and not valid[-3:].any() and not valid[:, -5:].any()
    assert (warped[~valid] == 0).all()


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.float32, np.float64, bool])
def test_warp_image_keeps_dtype_and_nearest_keeps_labels(dtype):
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 4, (40, 50)).astype(dtype)
    out, valid = warp_image(labels, _shift(2.3, -1.2), (30, 45), interpolation="nearest")
    assert out.dtype == labels.dtype and out.shape == (30, 45)
    assert set(np.unique(out[valid]).tolist()) <= set(np.unique(labels).tolist())
    assert np.array_equal(out[5:, :40], labels[4:29, 2:42])  # round(x + 2.3) = x + 2, round(y - 1.2) = y - 1
    lin, _ = warp_image(labels, _shift(2.3, -1.2), (30, 45))
    assert lin.dtype == labels.dtype


def test_warp_image_many_channels_and_errors():
    img = np.random.default_rng(0).random((20, 20, 6)).astype(np.float32)
    out, valid = warp_image(img, _shift(1, 1), (20, 20))
    assert out.shape == (20, 20, 6)
    assert np.allclose(out[:-1, :-1], img[1:, 1:])
    one, _ = warp_image(img[:, :, :1], _shift(0, 0), (20, 20))
    assert one.shape == (20, 20, 1)
    with pytest.raises(InputError, match="interpolation"):
        warp_image(img, _shift(0, 0), (5, 5), interpolation="cubic")
    with pytest.raises(InputError, match="image_b"):
        warp_image(np.zeros((0, 4)), _shift(0, 0), (5, 5))
    with pytest.raises(InputError, match="shape_a"):
        warp_image(img, _shift(0, 0), (0, 5))


@pytest.mark.parametrize("shape,dtype", [((40, 50), np.float32), ((40, 50, 1), np.float64), ((40, 50, 3), np.uint8),
                                         ((40, 50, 6), np.float32)])
def test_warp_image_linear_is_zero_exactly_outside_b_and_keeps_values_inside(shape, dtype):
    rng = np.random.default_rng(1)
    img = (rng.uniform(-100, 100, shape) if np.dtype(dtype).kind == "f" else rng.integers(0, 256, shape)).astype(dtype)
    out, valid = warp_image(img, _shift(3, -2), (40, 50))  # out[r, c] = img[r - 2, c + 3]
    assert out.shape == shape and out.dtype == img.dtype
    assert valid[2:, :47].all() and not valid[:2].any() and not valid[:, 47:].any()
    assert (out[~valid] == 0).all()
    assert np.array_equal(out[2:, :47], img[:-2, 3:])  # whole-pixel shifts: the values themselves
    # within float32 round-off of b's last pixel centre still counts as inside
    _, valid_edge = warp_image(img, _shift(0.0005, 0), (40, 50))
    assert valid_edge.all()


def test_fold_fraction_on_a_lattice_matches_the_full_count():
    bump = KernelWarp(dim=2, src_mean=np.array([150.0, 100.0]), src_scale=100.0, dst_mean=np.array([150.0, 100.0]),
                      dst_scale=100.0, linear=None, beta=20.0, centers=np.zeros((1, 2)),
                      weights=np.array([[-0.6, 0.0]]))
    full = fold_fraction(bump, (200, 300))
    sampled = fold_fraction(bump, (200, 300), max_samples=6000)
    assert full > 0.01 and abs(full - sampled) < 0.005


def test_remap_planes_equals_remap_image_channel_first():
    rng = np.random.default_rng(2)
    field = rng.uniform(-5, 5, (40, 50, 9)).astype(np.float32)
    pos = sample_positions(_shift(2.3, -1.6), (44, 52))  # partly outside b
    out, valid = remap_image(field, pos, "linear")
    planes, valid_p = remap_planes(field, pos)
    assert planes.shape == (9, 44, 52) and np.array_equal(valid_p, valid) and (~valid).any()
    assert np.array_equal(planes, out.transpose(2, 0, 1))


def test_sample_positions_on_a_grown_frame_are_the_map_at_a_s_pixels_shifted_by_the_margin():
    f = _bendy_warp(seed=3)
    h, w, m = 60, 80, 7
    pos = sample_positions(f, (h, w))
    grown = sample_positions(f, (h, w), margin=m)
    assert pos.shape == (h, w, 2) and grown.shape == (h + 2 * m, w + 2 * m, 2) and grown.dtype == np.float32
    # the grown frame's pixel (row, col) is a's (x, y) = (col - m, row - m)
    np.testing.assert_allclose(grown[m:m + h, m:m + w], pos, atol=0.05)
    corners = np.array([[-m, -m], [w - 1 + m, -m], [-m, h - 1 + m], [w - 1 + m, h - 1 + m]], float)
    np.testing.assert_allclose(grown[[0, 0, -1, -1], [0, -1, 0, -1]], f(corners), atol=0.05)


def test_pixel_grids_are_exact_and_their_cache_stays_within_its_budget():
    from reglib.dense._flow import pixel_grid

    seen = {}
    for h, w in [(3, 5), (600, 800), (2100, 2100), (600, 800), (1500, 1500), (1500, 1501)]:
        grid = pixel_grid(h, w)
        assert grid.shape == (h, w, 2) and not grid.flags.writeable
        assert grid[-1, -1, 0] == w - 1 and grid[-1, -1, 1] == h - 1 and grid[0, 3 % w, 0] == 3 % w
        assert seen.setdefault((h, w), grid) is grid  # a grid asked for again is the one kept
    # over the 32 MiB budget on its own: made each time, not kept
    assert pixel_grid(2100, 2100) is not seen[(2100, 2100)]
    # the two 1500 px grids do not fit together: the least recently used went first
    assert pixel_grid(1500, 1501) is seen[(1500, 1501)]
    assert pixel_grid(3, 5) is not seen[(3, 5)] and pixel_grid(1500, 1500) is not seen[(1500, 1500)]


def test_warp_image_takes_what_match_images_takes(tmp_path):
    from reglib.io import encode_png

    img = np.random.default_rng(5).integers(0, 256, (30, 40, 3), dtype=np.uint8)
    data = encode_png(img)
    (tmp_path / "b.png").write_bytes(data)
    want, want_valid = warp_image(img, _shift(2.5, -1.0), (25, 35))
    for source in (tmp_path / "b.png", str(tmp_path / "b.png"), data, bytearray(data)):
        got, valid = warp_image(source, _shift(2.5, -1.0), (25, 35))
        assert np.array_equal(got, want) and np.array_equal(valid, want_valid)
    with pytest.raises(InputError, match="`image_b` must be an image array, a path or encoded bytes, got list"):
        warp_image(img.tolist(), _shift(0, 0), (5, 5))
    with pytest.raises(InputError, match="`image_b`: no such file"):
        warp_image(tmp_path / "missing.png", _shift(0, 0), (5, 5))
    with pytest.raises(InputError, match="image_b"):
        warp_image(b"not an image", _shift(0, 0), (5, 5))
