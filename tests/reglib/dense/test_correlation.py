"""Tests of the correlation search: guided dense matching (reglib.dense._guided), the grid search, near windows
included (reglib.dense._correlation), multi-channel correlation (reglib.dense._ncc) and the texture measure
(reglib.dense._texture). Pairs are made from scikit-image sample images with known warps."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import KernelWarp
from reglib.dense import guided_matches, texture_map
from reglib.dense._correlation import SearchSpec, Thresholds, search_grid
from reglib.dense._ncc import multi_channel_maps, multi_channel_ncc
from reglib.dense._texture import texture_at
from reglib.errors import InputError


def test_guided_matches_recover_the_residual_motion():
    a = skimage.data.camera().astype(np.float32)
    truth = np.float32([[1, 0, 3.4], [0, 1, -2.2]])  # b(p + t) = a(p)
    b = cv2.warpAffine(a, truth, (512, 512), flags=cv2.INTER_CUBIC)
    src, dst, ncc = guided_matches(a, b, KernelWarp.identity(2), step=16, radius=6)
    assert len(src) > 300
    err = np.linalg.norm(dst - src - [3.4, -2.2], axis=1)
    assert np.median(err) < 0.25  # parabola sub-pixel peaks: some pull towards whole pixels
    assert np.mean(err < 1.0) > 0.9
    assert (ncc >= 0.5).all()
    # mask_a keeps only grid points inside it
    mask = np.zeros((512, 512), bool)
    mask[:, :256] = True
    src2, _, _ = guided_matches(a, b, KernelWarp.identity(2), step=16, radius=6, mask_a=mask)
    assert 0 < len(src2) < len(src) and (src2[:, 0] < 256).all()
    # stricter thresholds keep fewer matches, each passing them
    src3, _, ncc3 = guided_matches(a, b, KernelWarp.identity(2), step=16, radius=6,
                                   thresholds=Thresholds(min_ncc=0.95, min_sharpness=0.2))
    assert 0 < len(src3) < len(src) and (ncc3 >= 0.95).all()


def test_guided_matches_reach_the_border_of_a_and_of_b():
    a = skimage.data.camera().astype(np.float32)
    b = cv2.warpAffine(a, np.float32([[1, 0, 3.4], [0, 1, -2.2]]), (512, 512), flags=cv2.INTER_CUBIC)
    radius, hp = 12, 5
    src, dst, _ = guided_matches(a, b, KernelWarp.identity(2), step=8, radius=radius, half_patch=hp)
    err = np.linalg.norm(dst - src - [3.4, -2.2], axis=1)
    assert np.mean(err < 1.0) > 0.9
    # grid points closer to a's border than the search radius are searched too (b is resampled beyond a's frame)
    near = (src[:, 0] < radius + hp) | (src[:, 1] < radius + hp) | (src[:, 0] > 511 - radius - hp) \
        | (src[:, 1] > 511 - radius - hp)
    assert near.sum() > 50 and np.median(err[near]) < 0.5
    # no match lands where its patch would leave b's frame
    assert (dst >= hp - 0.5).all() and (dst <= 511 - hp + 0.5).all()


def test_guided_matches_on_a_textureless_or_tiny_image_is_empty():
    flat = np.full((100, 100), 7, np.float32)
    src, dst, ncc = guided_matches(flat, flat, KernelWarp.identity(2))
    assert src.shape == (0, 2) and dst.shape == (0, 2) and ncc.shape == (0,)
    tiny = np.zeros((10, 10), np.float32)
    assert guided_matches(tiny, tiny, KernelWarp.identity(2))[0].shape == (0, 2)
    empty = search_grid(tiny[:, :, None], tiny[:, :, None], KernelWarp.identity(2), SearchSpec())
    assert empty.grid.shape == (0, 2) and empty.n_grid == 0


def test_guided_matches_correlate_multi_channel_fields(fields):
    a = skimage.data.camera().astype(np.float32)
    b = cv2.warpAffine(a, np.float32([[1, 0, 2.6], [0, 1, -1.4]]), (512, 512), flags=cv2.INTER_CUBIC)
    fa, fb = fields(a), fields(b)
    # each channel of b under its own gain and offset: per-channel zero-mean NCC does not care
    fb = fb * np.float32([0.5, 3.0, 1.0]) + np.float32([0.2, -0.1, 0.0])
    src, dst, ncc = guided_matches(fa, fb, KernelWarp.identity(2), step=24, radius=5)
    assert len(src) > 150
    assert np.isfinite(ncc).all() and (ncc <= 1.0 + 1e-5).all()  # the flat channel is left out, not NaN
    err = np.linalg.norm(dst - src - [2.6, -1.4], axis=1)
    assert np.median(err) < 0.3
    # one channel is the grey image itself: the same answer as the grey call
    s1, d1, _ = guided_matches(a, b, KernelWarp.identity(2), step=24, radius=5)
    s3, d3, _ = guided_matches(a[:, :, None], b[:, :, None], KernelWarp.identity(2), step=24, radius=5)
    assert np.array_equal(s1, s3) and np.allclose(d1, d3)
    with pytest.raises(InputError, match="same C"):
        guided_matches(fa, fb[:, :, :2], KernelWarp.identity(2))
    with pytest.raises(InputError, match=r"\(H, W\) or \(H, W, C\)"):
        guided_matches(a[None, :, :, None], b, KernelWarp.identity(2))


def test_batched_multi_channel_maps_and_grid_texture_equal_the_per_point_reference(fields):
    a = skimage.data.camera().astype(np.float32)[:160, :200]
    b = np.roll(a, (1, -2), axis=(0, 1))
    fa, fb = fields(a), fields(b)
    fa[40:80, 40:80, 0] = 3.0  # a channel flat in some templates: left out of their mean
    hp, r = 5, 3
    gy, gx = np.mgrid[hp:160 - hp - 2 * r:13, hp:200 - hp - 2 * r:11]
    gy, gx = gy.ravel(), gx.ravel()
    side = 2 * r + 1
    maps = np.empty((len(gy), side, side), np.float32)
    # fb plays the grown frame: the window of a's point (x, y) starts at (x - hp, y - hp) there
    multi_channel_maps(fa, np.ascontiguousarray(fb.transpose(2, 0, 1)), gy, gx, r, hp, maps)
    for i, (y, x) in enumerate(zip(gy, gx, strict=True)):
        window = fb[y - hp:y + 2 * r + hp + 1, x - hp:x + 2 * r + hp + 1]
        ref = multi_channel_ncc(fa[y - hp:y + hp + 1, x - hp:x + hp + 1], window)
        # the same sums in another order where the CPU's vector width differs: float32 rounding
        np.testing.assert_allclose(maps[i], ref, rtol=1e-5, atol=1e-6)
    # the texture at grid points only: the box filter's values (exactly for a grey image)
    for field, exact in ((a[:, :, None], True), (fa, False)):
        full = texture_map(field, hp)[gy, gx]
        at = texture_at(field, hp, gy, gx)
        assert np.array_equal(at, full) if exact else np.allclose(at, full, rtol=1e-5, atol=1e-6)


def test_near_grid_points_search_a_smaller_window_with_the_same_peaks():
    # a shift of 2.3 / -1.4 px: found within radius 10 as within 14 (OpenCV's correlation of a
    # smaller window differs in rounding; a wider window may hold a stronger, wrong peak); the
    # points flagged near are searched within 10 px only (a 12 px motion is missed there)
    a = skimage.data.camera().astype(np.float32)[:, :, None]
    b = cv2.warpAffine(a, np.float32([[1, 0, 2.3], [0, 1, -1.4]]), (512, 512), flags=cv2.INTER_CUBIC)[:, :, None]
    f = KernelWarp.identity(2)
    spec = SearchSpec(step=16, radius=14, half_patch=5)
    wide = search_grid(a, b, f, spec)
    split = search_grid(a, b, f, spec, near=lambda p: p[:, 0] < 256)
    both = wide.found & split.found
    assert both.mean() > 0.9
    close = np.linalg.norm(wide.offset[both] - split.offset[both], axis=1) < 0.01
    assert close.mean() > 0.97
    near_true = np.linalg.norm(split.offset[both] - [2.3, -1.4], axis=1) < 0.5
    assert near_true.mean() > 0.8  # (camera: parabola peaks and a flat sky)
    far = cv2.warpAffine(a, np.float32([[1, 0, 12.0], [0, 1, 0.0]]), (512, 512), flags=cv2.INTER_CUBIC)[:, :, None]
    split = search_grid(a, far, f, spec, near=lambda p: p[:, 0] < 256)
    left = split.grid[:, 0] < 256
    right_found = split.found[~left] & (np.abs(split.offset[~left, 0] - 12.0) < 0.5)
    assert right_found.mean() > 0.8  # the wide window finds the motion ...
    assert not (split.found[left] & (np.abs(split.offset[left, 0] - 12.0) < 0.5)).any()  # ... the near one cannot


def test_near_grid_points_of_a_multi_channel_field_search_the_smaller_window():
    grey = skimage.data.camera().astype(np.float32)
    a = np.dstack([grey, cv2.Sobel(grey, cv2.CV_32F, 1, 0)])
    shift = np.float32([[1, 0, 2.3], [0, 1, -1.4]])
    b = np.dstack([cv2.warpAffine(a[:, :, c], shift, (512, 512), flags=cv2.INTER_CUBIC) for c in range(2)])
    f = KernelWarp.identity(2)
    spec = SearchSpec(step=16, radius=14, half_patch=5)
    wide = search_grid(a, b, f, spec)
    split = search_grid(a, b, f, spec, near=lambda p: p[:, 0] < 256)
    both = wide.found & split.found
    assert both.mean() > 0.9
    assert (np.linalg.norm(wide.offset[both] - split.offset[both], axis=1) < 0.01).mean() > 0.97


def test_a_search_keeps_the_points_of_a_subset():
    a = skimage.data.camera().astype(np.float32)[:, :, None]
    b = np.roll(a, (1, 2), axis=(0, 1))
    s = search_grid(a, b, KernelWarp.identity(2), SearchSpec(step=32, radius=4, half_patch=5))
    keep = s.grid[:, 0] < 200
    sub = s.where(keep)
    assert 0 < sub.n_grid == int(keep.sum()) < len(s.grid)
    assert np.array_equal(sub.grid, s.grid[keep]) and np.array_equal(sub.offset, s.offset[keep])
    assert np.array_equal(sub.found, s.found[keep]) and np.array_equal(sub.ncc, s.ncc[keep])
