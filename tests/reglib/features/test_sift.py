"""Tests of reglib.features.sift: detection, exact coordinate mapping after resizing, matching."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data
from scipy.spatial import cKDTree

from reglib.errors import InputError
from reglib.features.sift import (
    check_mask,
    detect_sift,
    match_descriptors,
    resize_factor,
    to_gray_uint8,
)


def test_detect_shapes_bounds_cap_and_rootsift():
    g = skimage.data.camera()
    f = detect_sift(g, max_keypoints=300)
    assert f.points.shape == (300, 2) and f.descriptors.shape == (300, 128)
    assert f.descriptors.dtype == np.float32
    assert np.allclose(np.linalg.norm(f.descriptors, axis=1), 1.0, atol=1e-5)
    assert (f.points >= -0.5).all() and (f.points <= 511.5).all()


def test_detection_on_a_resized_copy_maps_back_to_original_pixels():
    g = skimage.data.camera()
    big = cv2.resize(g, (1024, 1024), interpolation=cv2.INTER_LINEAR)  # pixel x of g is 2 x + 0.5 of big
    direct = detect_sift(g, max_keypoints=500)
    mapped = detect_sift(big, max_keypoints=500, max_side=512)  # detected on a 512 copy, mapped to big
    expect = 2.0 * direct.points + 0.5
    dist, idx = cKDTree(expect).query(mapped.points)
    close = dist < 1.0
    assert close.mean() > 0.6
    # no systematic offset: forgetting the half-pixel centres would shift every point by 0.5 px
    bias = np.median(mapped.points[close] - expect[idx[close]], axis=0)
    assert np.abs(bias).max() < 0.1


def test_resize_factor():
    assert resize_factor((100, 200), 400) == (200, 100, 1.0, 1.0)
    w, h, sx, sy = resize_factor((1000, 3000), 1500)
    assert (w, h) == (1500, 500) and sx == 0.5 and sy == 0.5


def test_tiny_and_masked_out_images_have_no_keypoints():
    assert detect_sift(np.zeros((5, 5), np.uint8)).points.shape == (0, 2)
    g = skimage.data.camera()
    assert len(detect_sift(g, mask=np.zeros(g.shape, bool)).points) == 0


def test_match_descriptors_recovers_a_permutation():
    rng = np.random.default_rng(0)
    d = rng.random((50, 128)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    perm = rng.permutation(50)
    ia, ib = match_descriptors(d, d[perm], ratio=0.99)
    assert np.array_equal(ia, np.arange(50))
    assert np.array_equal(perm[ib], ia)
    ia, ib = match_descriptors(d, d[perm], ratio=1.0, mutual=True)
    assert len(ia) == 50


def test_ratio_test_and_mutual_check():
    a = np.array([[0.995, 0.005], [0.0, 1.0]], np.float32)
    b = np.array([[1.0, 0.0], [0.99, 0.01], [0.0, 1.0]], np.float32)
    ia, ib = match_descriptors(a, b, ratio=0.8)
    assert ia.tolist() == [1] and ib.tolist() == [2]  # the first is ambiguous
    ia, _ = match_descriptors(a, b, ratio=1.0)
    assert ia.tolist() == [0, 1]
    # b[0] and b[1] both want a[0]; only b[0] <-> a[0] is mutual
    ia, ib = match_descriptors(b, a, ratio=1.0, mutual=True)
    assert ia.tolist() == [0, 2] and ib.tolist() == [0, 1]
    e = np.zeros((0, 2), np.float32)
    assert match_descriptors(e, a)[0].shape == (0,)
    assert match_descriptors(a, b[:1], ratio=1.0)[0].tolist() == [0, 1]


def test_to_gray_uint8():
    rgb = skimage.data.astronaut()
    assert to_gray_uint8(rgb).shape == rgb.shape[:2]
    assert to_gray_uint8(np.full((3, 3), 65535, np.uint16)).max() == 255
    assert to_gray_uint8(np.full((3, 3), 0.5)).max() == 128
    assert to_gray_uint8(np.full((3, 3), -7.0)).max() == 0
    assert to_gray_uint8(np.array([[-1.0, 3.0]])).tolist() == [[0, 255]]


def test_check_mask():
    assert check_mask(None, (3, 3), "m") is None
    assert check_mask(np.ones((3, 3, 1)), (3, 3), "m").dtype == bool
    with pytest.raises(InputError, match="mask_a"):
        check_mask(np.ones((2, 3)), (3, 3), "mask_a")
