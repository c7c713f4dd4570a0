"""Tests of reglib.dense._refine: the coarse-to-fine dense stage and its working frames. Pairs are made from
scikit-image sample images with known warps (tests/reglib/dense/conftest.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import KernelWarp
from reglib._transforms import LinearPart
from reglib.dense import DenseOptions, refine_dense
from reglib.dense._fields import area_resized
from reglib.dense._refine import barely_moved, working_frames
from reglib.errors import InputError


def _mean_error(f: KernelWarp, g, size: int) -> float:
    q = np.mgrid[24:size - 24:8, 24:size - 24:8].reshape(2, -1).T[:, ::-1].astype(float)
    return float(np.linalg.norm(f(g(q)) - q, axis=1).mean())


def test_refine_dense_converges_from_a_rough_start_under_strong_deformation(make_bent_pair, make_affine, fields):
    size = 256
    a, b, g, c, rot = make_bent_pair(size)
    # a rough first estimate: the similarity only (no bumps), and 20, 12 px off on top: beyond the 14 px search
    # radius at full resolution, so only the coarse pyramid levels can bring it in
    inv = np.linalg.inv(rot)
    f0 = make_affine(np.c_[inv, c - inv @ c + [20.0, 12.0]])
    assert _mean_error(f0, g, size) > 20.0
    opts = DenseOptions(max_side=size, step=8)
    res = refine_dense(a, b, f0, opts, np.random.default_rng(0))
    assert res.fitted and res.n_dense > 300 and res.rounds >= 3 and not res.kept_first
    assert _mean_error(res.transform, g, size) < 0.3
    # the final basis follows the support (one centre per 4 matches at most) at a fixed kernel width
    assert 15 < res.transform.n_centers <= res.n_dense / 4 + 1
    assert res.transform.beta == pytest.approx(1.8, rel=0.35)
    # more rounds while they improve: one round per level stops short (1.2 leaves room for
    # rounding-level changes of the fits)
    one = refine_dense(a, b, f0, DenseOptions(max_side=size, step=8, rounds=1), np.random.default_rng(0))
    assert one.fitted and one.rounds < res.rounds
    assert _mean_error(one.transform, g, size) > 1.2 * _mean_error(res.transform, g, size)
    # the same pair through descriptor fields instead of grey levels (the multimodal path)
    res3 = refine_dense(fields(a), fields(b), f0, opts, np.random.default_rng(0))
    assert res3.fitted and _mean_error(res3.transform, g, size) < 0.5
    # with the coarser levels' narrow-kernel detail (DenseOptions.detail): as accurate on this pair
    det = refine_dense(a, b, f0, DenseOptions(max_side=size, step=8, detail=True), np.random.default_rng(0))
    assert det.fitted and not det.kept_first and _mean_error(det.transform, g, size) < 0.3


def test_refine_dense_on_nine_channel_fields_larger_than_the_working_size(make_bent_pair, make_affine):
    # a structure field (9 channels) of an image over max_side is matched on a resized copy: OpenCV's
    # area resampling takes at most 4 channels at such a scale (this raised cv2.error before)
    from reglib.features import structure_image

    size = 256
    a, b, g, c, rot = make_bent_pair(size)
    fa, fb = structure_image(a), structure_image(b)
    assert fa.shape == (size, size, 9)
    inv = np.linalg.inv(rot)
    f0 = make_affine(np.c_[inv, c - inv @ c + [6.0, -4.0]])
    res = refine_dense(fa, fb, f0, DenseOptions(max_side=180, step=8), np.random.default_rng(0))
    assert res.fitted and res.confidence.shape == (size, size)
    assert _mean_error(res.transform, g, size) < min(1.0, 0.2 * _mean_error(f0, g, size))
    # the resized copy: each channel as OpenCV resizes it alone
    small = area_resized(fa, 0.7)
    want = np.dstack([cv2.resize(fa[:, :, k], (0, 0), fx=0.7, fy=0.7, interpolation=cv2.INTER_AREA) for k in range(9)])
    assert small.shape == want.shape and np.array_equal(small, want)
    assert area_resized(fa[:, :, :1], 0.7).shape == (want.shape[0], want.shape[1], 1)


def test_refine_dense_finds_nothing_on_flat_images():
    flat = np.full((128, 128), 9, np.float32)
    f0 = KernelWarp.identity(2)
    res = refine_dense(flat, flat, f0, DenseOptions(), np.random.default_rng(0))
    # no fit: the first estimate comes back, with its own (empty) support
    assert not res.fitted and res.transform is f0 and res.n_dense == 0 and not res.converged
    assert not res.kept_first and res.rounds >= 1
    assert res.confidence.shape == (128, 128) and res.confidence.dtype == np.float32 and res.confidence.max() == 0.0


def test_refine_dense_input_errors():
    a = np.zeros((64, 64), np.float32)
    with pytest.raises(InputError, match="same C"):
        refine_dense(a, np.zeros((64, 64, 2), np.float32), KernelWarp.identity(2), DenseOptions(),
                     np.random.default_rng(0))
    with pytest.raises(InputError, match="radius"):
        DenseOptions(radius=0)
    with pytest.raises(InputError, match="method"):
        DenseOptions(method="ransac")


def test_working_frames_resize_images_and_masks_over_the_working_size():
    a = skimage.data.camera().astype(np.float32)
    mask = np.zeros(a.shape, bool)
    mask[:, :256] = True
    frames = working_frames(a, a[:400], DenseOptions(max_side=256), mask, None)
    assert frames.a.shape == (256, 256, 1) and frames.scale_a == 0.5 and frames.shape_a == (512, 512)
    assert frames.b.shape[2] == 1 and frames.scale_b == pytest.approx(256 / 512)
    assert frames.mask_a.shape == (256, 256) and frames.mask_a[:, :120].all() and not frames.mask_a[:, 136:].any()
    assert frames.mask_b is None and frames.min_std == 2.0 and frames.std.shape == (256, 256)
    same = working_frames(a, a, DenseOptions())
    assert same.scale_a == 1.0 and same.a.shape == (512, 512, 1)


def test_barely_moved_measures_the_last_rounds_move_in_level_pixels():
    before = KernelWarp.identity(2)
    after = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.array([6.0, 0.0]), dst_scale=1.0,
                       linear=LinearPart(kind="affine", matrix=np.c_[np.eye(2), [0.0, 0.0]]), beta=1.0,
                       centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    pts = np.array([[10.0, 10.0]])
    assert not barely_moved(before, after, 1.0, 1.0, pts)[0]  # 6 px at full size: more than 4
    assert barely_moved(before, after, 0.5, 0.5, pts)[0]  # 3 px on a level of half the size
