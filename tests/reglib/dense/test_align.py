"""Tests of reglib.dense._align: rigid alignment by normalized mutual information."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data

from reglib.dense._align import RigidAlignment, align_rigid

CAMERA = data.camera()  # (512, 512) uint8
H, W = CAMERA.shape


# ----------------------------------------------------------------------------- align_rigid

def _pseudo_colour_pet(sensor, angle: float, shift: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A 'PET' of the camera image: moved rigidly, blurred hard, shown in the JET colour scale."""
    m = sensor.similarity(angle, 1.0, shift)
    moved = cv2.warpAffine(CAMERA, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    blurred = cv2.GaussianBlur(sensor.remap(moved), (0, 0), 6.0)
    return cv2.cvtColor(cv2.applyColorMap(blurred, cv2.COLORMAP_JET), cv2.COLOR_BGR2RGB), m


def test_align_rigid_recovers_a_rigid_map_across_a_pseudo_colour_scale(sensor):
    b, m = _pseudo_colour_pet(sensor, 7.0, (-20.0, 14.0))
    res = align_rigid(CAMERA, b, compare=lambda p: sensor.apply(m, p))
    assert isinstance(res, RigidAlignment)
    matrix, nmi, nmi_true = res.matrix, res.nmi, res.nmi_compare
    assert matrix.shape == (2, 3) and res.peak > 3.0
    grid = np.stack(np.meshgrid(np.linspace(60, 450, 6), np.linspace(60, 450, 6)), -1).reshape(-1, 2)
    assert np.abs(grid @ matrix[:, :2].T + matrix[:, 2] - sensor.apply(m, grid)).max() < 3.0
    assert 1.0 < nmi < 2.0 and nmi_true == pytest.approx(nmi, abs=0.02)
    nmi_identity = align_rigid(CAMERA, b, compare=lambda p: np.asarray(p, float)).nmi_compare
    assert nmi_identity < nmi - 0.01


def test_align_rigid_handles_images_of_different_sizes(sensor):
    """Rigid in pixels: a crop of b (a different size and aspect) gives the same map, shifted."""
    b, m = _pseudo_colour_pet(sensor, -4.0, (10.0, 6.0))
    crop = b[32:480, 16:500]
    res = align_rigid(CAMERA, crop)
    assert res.nmi_compare == 0.0  # nothing to compare
    matrix = res.matrix
    pts = np.array([[150.0, 150.0], [350.0, 300.0], [250.0, 400.0]])
    want = sensor.apply(m, pts) - [16.0, 32.0]
    assert np.abs(pts @ matrix[:, :2].T + matrix[:, 2] - want).max() < 3.0
