"""Tests of reglib.features._structure: structure fields and the refinement of cross-modal matches."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data

from reglib.errors import InputError
from reglib.features import refine_matches, structure_image

CAMERA = data.camera()  # (512, 512) uint8
H, W = CAMERA.shape


# ----------------------------------------------------------------------------- refine_matches

def test_refine_moves_near_misses_onto_the_truth(sensor):
    b, m = sensor.pair(0.0, 1.0, (6.0, 3.0))
    rng = np.random.default_rng(1)
    src = rng.uniform(80, 430, (60, 2))
    truth = sensor.apply(m, src)
    dst = truth + rng.uniform(-5, 5, truth.shape)
    new, score = refine_matches(CAMERA, b, src, dst)
    assert new.shape == (60, 2) and score.shape == (60,)
    before = np.linalg.norm(dst - truth, axis=1)
    after = np.linalg.norm(new - truth, axis=1)
    assert np.median(after) < 1.0 < np.median(before)
    empty, s0 = refine_matches(CAMERA, b, np.zeros((0, 2)), np.zeros((0, 2)))
    assert empty.shape == (0, 2) and s0.shape == (0,)
    with pytest.raises(InputError, match="src"):
        refine_matches(CAMERA, b, src, dst[:3])


# ----------------------------------------------------------------------------- structure_image

def test_structure_image_is_unit_scaled_and_contrast_invariant():
    img = CAMERA.astype(np.float64)
    f = structure_image(img)
    g = structure_image(3.0 * img + 100.0)
    assert f.shape == (H, W, 9) and f.dtype == np.float32
    norm = np.linalg.norm(f, axis=2)
    assert norm.max() <= 1.0 + 1e-5 and np.median(norm) > 0.5
    np.testing.assert_allclose(f, g, atol=1e-4)
    with pytest.raises(InputError, match="image"):
        structure_image(np.zeros((2, 2, 2, 2)))


def test_structure_correlation_locates_a_remapped_patch(sensor):
    """Zero-mean NCC of two structure fields peaks at the true shift across the remap."""
    b, _ = sensor.pair(0.0, 1.0, (9.0, -4.0))
    fa, fb = structure_image(CAMERA), structure_image(b)
    tpl = fa[200:260, 200:260]
    win = fb[180:290, 190:300]
    score = sum(cv2.matchTemplate(np.ascontiguousarray(win[:, :, c:c + 3]),
                                  np.ascontiguousarray(tpl[:, :, c:c + 3]), cv2.TM_CCOEFF_NORMED)
                for c in range(0, 9, 3))
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    assert (190 + ix - 200, 180 + iy - 200) == (9, -4)
