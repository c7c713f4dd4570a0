"""Tests of reglib.features._rift: phase-congruency keypoints, MIM descriptors, rotation-hypothesis matching."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.distance import cdist
from skimage import data

from reglib import filter_matches
from reglib.errors import InputError
from reglib.features import N_ROTATIONS, detect_multimodal, detect_sift, match_descriptors, match_multimodal

CAMERA = data.camera()  # (512, 512) uint8
H, W = CAMERA.shape


@pytest.fixture(scope="module")
def feat_a():
    return detect_multimodal(CAMERA)


# ----------------------------------------------------------------------------- detect_multimodal

def test_detect_shapes_and_coordinates_in_original_pixels(feat_a):
    f = feat_a
    assert f.points.dtype == np.float64 and f.points.shape == (1500, 2)
    assert f.descriptors.dtype == np.float32 and f.descriptors.shape == (1500, N_ROTATIONS * 216)
    assert f.sizes.shape == f.angles.shape == (1500,)
    blocks = f.descriptors.reshape(1500, N_ROTATIONS, 216)
    np.testing.assert_allclose(np.linalg.norm(blocks, axis=2), 1.0, atol=1e-5)
    big = cv2.resize(CAMERA, (1024, 768), interpolation=cv2.INTER_CUBIC)  # anisotropic, > max_side
    g = detect_multimodal(big, max_keypoints=200)
    assert g.points[:, 0].max() > 900 and g.points[:, 1].max() > 650
    assert g.points.min() >= 0 and g.points[:, 0].max() < 1024 and g.points[:, 1].max() < 768


def test_detect_is_deterministic_and_dtype_robust(feat_a):
    again = detect_multimodal(CAMERA)
    np.testing.assert_array_equal(again.points, feat_a.points)
    np.testing.assert_array_equal(again.descriptors, feat_a.descriptors)
    kw = {"max_keypoints": 300, "n_levels": 1}
    f8 = detect_multimodal(CAMERA, **kw)
    f16 = detect_multimodal(CAMERA.astype(np.uint16) * 256 + 3, **kw)
    f32 = detect_multimodal(CAMERA.astype(np.float32) / 255.0 * 4000.0 - 10.0, **kw)
    for f in (f16, f32):
        assert len(f.points) == len(f8.points)
        nearest = cdist(f.points, f8.points).min(axis=1)
        assert np.mean(nearest < 0.5) > 0.9


def test_detect_mask_upright_and_empty():
    mask = np.zeros((H, W), bool)
    mask[:, :256] = True
    f = detect_multimodal(CAMERA, mask=mask, max_keypoints=200, rotation_invariant=False, n_levels=1)
    assert len(f.points) > 50 and f.points[:, 0].max() < 257
    assert f.descriptors.shape == (len(f.points), 216)
    empty = detect_multimodal(CAMERA[:10, :10])
    assert empty.points.shape == (0, 2) and empty.descriptors.shape == (0, N_ROTATIONS * 216)
    none = detect_multimodal(CAMERA, mask=np.zeros((H, W), bool))
    assert none.points.shape == (0, 2)
    flat = detect_multimodal(np.full((64, 64), 9, np.uint8))
    assert flat.points.shape == (0, 2)


@pytest.mark.parametrize("kwargs, match", [
    ({"image": np.zeros((4, 4, 2, 1))}, "image"),
    ({"image": np.zeros((32, 32), complex)}, "image"),
    ({"image": CAMERA, "mask": np.ones((5, 5))}, "mask"),
    ({"image": CAMERA, "max_keypoints": 0}, "max_keypoints"),
    ({"image": CAMERA, "n_levels": 0}, "n_levels"),
    ({"image": CAMERA, "edge_share": 2.0}, "edge_share"),
])
def test_detect_errors(kwargs, match):
    with pytest.raises(InputError, match=match):
        detect_multimodal(**kwargs)


# ----------------------------------------------------------------------------- matching, known transforms

@pytest.mark.parametrize("angle, scale, shift", [
    (0.0, 1.0, (12.0, -7.0)),   # intensity remap only (and a shift)
    (-33.0, 1.25, (0.0, 0.0)),  # rotation between hypotheses and zoom, remapped
    (90.0, 0.85, (5.0, 5.0)),   # a quarter turn and shrink, remapped
])
def test_matches_are_right_under_remap_rotation_and_scale(sensor, feat_a, angle, scale, shift):
    b, m = sensor.pair(angle, scale, shift)
    fb = detect_multimodal(b)
    ia, ib = match_multimodal(feat_a.descriptors, fb.descriptors)
    assert len(ia) >= 40
    err = np.linalg.norm(sensor.apply(m, feat_a.points[ia]) - fb.points[ib], axis=1)
    assert np.mean(err < 3.0) > 0.6
    # through the estimator: the recovered map is right where the image has content
    res = filter_matches(feat_a.points[ia], fb.points[ib], options={"n_centers": 0, "max_centers": 0}, rng=0)
    grid = np.stack(np.meshgrid(np.linspace(100, 400, 7), np.linspace(100, 400, 7)), -1).reshape(-1, 2)
    assert np.abs(res.transform(grid) - sensor.apply(m, grid)).max() < 2.0


def test_sift_fails_where_multimodal_works(sensor, feat_a):
    """The reason for the module: SIFT's descriptors do not survive the remap."""
    b, m = sensor.pair(0.0, 1.0, (12.0, -7.0))
    sa, sb = detect_sift(CAMERA), detect_sift(b)
    ia, ib = match_descriptors(sa.descriptors, sb.descriptors, ratio=0.8)
    err = np.linalg.norm(sensor.apply(m, sa.points[ia]) - sb.points[ib], axis=1)
    assert np.count_nonzero(err < 3.0) < 40


def test_match_multimodal_empty_errors_and_ratio():
    d = np.eye(24, dtype=np.float32)[:5]
    ia, ib = match_multimodal(d[:0], d, n_rotations=1)
    assert ia.shape == ib.shape == (0,) and ia.dtype == np.intp
    ia, ib = match_multimodal(d, d, n_rotations=1, ratio=1.0, mutual=False)
    np.testing.assert_array_equal(ia, ib)
    with pytest.raises(InputError, match="n_rotations"):
        match_multimodal(d, d, n_rotations=5)
    with pytest.raises(InputError, match="desc_a"):
        match_multimodal(d, d[:, :12], n_rotations=1)
    with pytest.raises(InputError, match="ratio"):
        match_multimodal(d, d, n_rotations=1, ratio=0.0)
