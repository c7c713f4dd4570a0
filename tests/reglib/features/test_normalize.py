"""Tests of reglib.features._normalize: intensity normalisation, normalized images passed along."""
from __future__ import annotations

import numpy as np
import pytest
import skimage.data

from reglib.errors import InputError
from reglib.features import (
    NormalizedImage,
    check_mask,
    detect_multimodal,
    normalize_intensity,
    refine_matches,
    structure_image,
    to_gray_uint8,
)

# ----------------------------------------------------------------------------- normalize_intensity

def test_normalize_percentile_stretch_ignores_hot_pixels():
    rng = np.random.default_rng(0)
    img = rng.integers(1000, 2000, (64, 64)).astype(np.uint16)
    img[0, :3] = 65535  # three hot pixels
    out = normalize_intensity(img)
    assert out.dtype == np.float32 and out.shape == img.shape
    assert 0.0 <= out.min() and out.max() <= 1.0
    assert np.median(out) == pytest.approx(0.5, abs=0.05)  # content is not squeezed to the bottom


def test_normalize_float_colour_and_constant():
    rgb = np.zeros((8, 8, 3), np.float64)
    rgb[:, 4:] = [10.0, 20.0, 30.0]
    out = normalize_intensity(rgb, low=0, high=100)
    assert out.shape == (8, 8) and out[:, :4].max() == 0.0 and out[:, 4:].min() == 1.0
    assert not normalize_intensity(np.full((5, 5), 7.0)).any()
    nan = np.full((4, 4), np.nan)
    assert np.all(np.isfinite(normalize_intensity(nan)))


# ----------------------------------------------------------------------------- NormalizedImage

def test_a_normalized_image_gives_the_numbers_of_the_image_itself():
    """Normalized once and passed along, the multimodal steps answer exactly as on the image."""
    img = skimage.data.camera()[::2, ::2].astype(np.uint16) * 200 + 7
    moved = np.roll(img, (3, -2), axis=(0, 1))
    norm, norm_moved = NormalizedImage.of(img), NormalizedImage.of(moved)
    np.testing.assert_array_equal(norm.gray, normalize_intensity(img))
    assert norm.shape == img.shape and not norm.gray.flags.writeable
    kw = {"max_keypoints": 200, "n_levels": 1}
    f, g = detect_multimodal(img, **kw), detect_multimodal(norm, **kw)
    np.testing.assert_array_equal(f.points, g.points)
    np.testing.assert_array_equal(f.descriptors, g.descriptors)
    np.testing.assert_array_equal(structure_image(img), structure_image(norm))
    src = f.points[:20]
    dst = src + [-2.0, 3.0]
    for x, y in zip(refine_matches(img, moved, src, dst), refine_matches(norm, norm_moved, src, dst), strict=True):
        np.testing.assert_array_equal(x, y)


def test_normalized_image_errors():
    with pytest.raises(InputError, match="image"):
        NormalizedImage.of(np.zeros((4, 4, 2, 1)))
    with pytest.raises(InputError, match="image"):
        NormalizedImage.of(np.zeros((8, 8), complex))


# ----------------------------------------------------------------------------- grey copies and masks

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
