"""Images as the fields store them: 12 bits in uint16, float in [0, 1], int32, RGB float64, many bands."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data

import reglib
from reglib import io
from reglib.errors import InputError
from reglib.features import to_gray_uint8


@pytest.fixture(scope="module")
def green_pair():
    """The astronaut's green channel and a copy under a smooth warp of a few pixels (8 bits)."""
    g = skimage.data.astronaut()[:, :, 1]
    h, w = g.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    b = cv2.remap(g, xx + 3.0 * np.sin(yy / 60.0), yy + 2.5 * np.cos(xx / 70.0), cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REFLECT)
    return g, b


def _sift(a, b, **options):
    return reglib.match_images(a, b, features="sift", rng=0, options={"dense": False, **options})


@pytest.fixture(scope="module")
def eight_bit_inliers(green_pair):
    m = _sift(*green_pair)
    assert m.converged and m.n_inliers > 300
    return m.n_inliers


@pytest.mark.parametrize("depth", ["uint16 0-4000", "float32 0-1", "int32 -5000..5000", "float64 HU"])
def test_sift_finds_the_8_bit_inliers_at_any_depth(green_pair, eight_bit_inliers, depth):
    convert = {"uint16 0-4000": lambda x: np.round(x * (4000 / 255)).astype(np.uint16),
               "float32 0-1": lambda x: (x / 255.0).astype(np.float32),
               "int32 -5000..5000": lambda x: (x.astype(np.int32) * 40 - 5000),
               "float64 HU": lambda x: x * 8.0 - 1024.0}[depth]
    m = _sift(*(convert(x) for x in green_pair))
    assert m.converged and m.n_inliers >= 0.8 * eight_bit_inliers, (m.n_inliers, eight_bit_inliers)


def test_the_grey_copy_of_12_bits_is_the_8_bit_one(green_pair):
    g = green_pair[0]
    twelve = np.round(g * (4000 / 255)).astype(np.uint16)
    lo, hi = np.percentile(g, [0.5, 99.5])  # the rule: these percentiles become 0 and 255
    want = np.clip(np.round((g - lo) * 255 / (hi - lo)), 0, 255)
    assert np.abs(to_gray_uint8(twelve).astype(int) - want).max() <= 1
    assert np.array_equal(to_gray_uint8(g), g)  # 8 bits keep their values


def test_a_few_hot_pixels_do_not_squeeze_the_range(green_pair):
    img = np.round(green_pair[0] * (4000 / 255)).astype(np.uint16)
    img[:3, :3] = 65535
    assert np.percentile(to_gray_uint8(img), 99) > 200


def test_the_band_option_picks_the_band_with_the_content(green_pair):
    a, b = green_pair
    rng = np.random.default_rng(0)
    noise = [rng.integers(0, 60000, a.shape + (3,), dtype=np.uint16) for _ in range(2)]
    four_a = np.dstack([noise[0], a.astype(np.uint16) * 200])  # content only in band 3 (e.g. near infrared)
    four_b = np.dstack([noise[1], b.astype(np.uint16) * 200])
    picked = _sift(four_a, four_b, band=3)
    assert picked.converged and picked.n_inliers > 300
    assert _sift(four_a, four_b).n_inliers < 50  # the default grey rendering sees the noise bands
    with pytest.raises(InputError, match="`band` 4 is not a band of the image: it has 4 band"):
        _sift(four_a, four_b, band=4)


@pytest.mark.parametrize("dtype", [np.float64, np.int32])
def test_rgb_of_any_dtype_reads_and_matches(green_pair, dtype):
    rgb = skimage.data.astronaut()[::2, ::2]
    data = io.encode_image((rgb * 3).astype(dtype), ".tif")
    img = io.read_image(data)
    assert img.dtype == dtype and np.array_equal(img, (rgb * 3).astype(dtype))  # RGB order kept
    m = reglib.match_images(data, data, rng=0, options={"dense": False})
    assert m.converged and m.n_inliers > 100
