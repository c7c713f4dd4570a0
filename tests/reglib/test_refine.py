"""Tests of reglib.refine: guided dense matching recovers the residual motion, empty where there is no texture."""
from __future__ import annotations

import cv2
import numpy as np
import skimage.data

from reglib import KernelWarp
from reglib.refine import guided_matches


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


def test_guided_matches_on_a_textureless_or_tiny_image_is_empty():
    flat = np.full((100, 100), 7, np.float32)
    src, dst, ncc = guided_matches(flat, flat, KernelWarp.identity(2))
    assert src.shape == (0, 2) and dst.shape == (0, 2) and ncc.shape == (0,)
    tiny = np.zeros((10, 10), np.float32)
    assert guided_matches(tiny, tiny, KernelWarp.identity(2))[0].shape == (0, 2)
