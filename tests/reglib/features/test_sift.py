"""Tests of reglib.features._sift: detection, exact coordinate mapping after resizing."""
from __future__ import annotations

import cv2
import numpy as np
import skimage.data
from scipy.spatial import cKDTree

from reglib.features import detect_sift, resize_factor, root_sift


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


def test_root_sift_is_the_square_root_of_the_l1_normalized_histogram():
    d = np.array([[4.0, 0.0, 12.0], [0.0, 0.0, 0.0]], np.float32)
    out = root_sift(d)
    np.testing.assert_allclose(out[0], [0.5, 0.0, np.sqrt(0.75)], rtol=1e-6)
    assert not out[1].any() and out.dtype == np.float32  # an empty histogram stays zero
    assert d[0, 0] == 4.0  # the caller's array is not changed
