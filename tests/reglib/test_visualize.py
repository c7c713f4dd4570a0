"""Tests of reglib.visualize: flow colours, match drawings, overlays, checkerboards."""
from __future__ import annotations

import numpy as np
import pytest

from reglib import ImageMatch, KernelWarp, visualize
from reglib.errors import InputError


def test_flow_to_color_wheel():
    flow = np.zeros((4, 6, 2), np.float32)
    flow[0, 0] = (1, 0)   # right: red end of the wheel
    flow[0, 1] = (-1, 0)  # left: cyan-blue
    flow[0, 2] = (0, 1)   # down
    flow[0, 3] = (0.5, 0)  # half magnitude: paler
    img = visualize.flow_to_color(flow)
    assert img.shape == (4, 6, 3) and img.dtype == np.uint8
    assert (img[1:] == 255).all()  # zero flow is white
    r, g, b = img[0, 0].astype(int)
    assert r > 200 and g < 40
    r, g, b = img[0, 1].astype(int)
    assert r < 40 and b > 200
    assert not np.array_equal(img[0, 2], img[0, 0])
    assert img[0, 3].astype(int).min() > img[0, 0].astype(int).min()
    assert np.array_equal(visualize.flow_to_color(flow, max_flow=2.0), visualize.flow_to_color(flow / 2, max_flow=1.0))
    with pytest.raises(InputError, match="flow"):
        visualize.flow_to_color(np.zeros((3, 3)))
    with pytest.raises(InputError, match="max_flow"):
        visualize.flow_to_color(flow, max_flow=0)


def _match() -> ImageMatch:
    src = np.array([[10.0, 10.0], [30.0, 40.0]])
    dst = np.array([[12.0, 10.0], [5.0, 45.0]])
    return ImageMatch(keypoints_a=src, keypoints_b=dst, src=src, dst=dst, inliers=np.array([True, False]),
                      scores=np.array([0.9, 0.0]), transform=KernelWarp.identity(2), converged=True, reason=None,
                      seed=0, shape_a=(50, 60), shape_b=(60, 40))


def test_draw_matches_colours_inliers_green_outliers_red():
    a = np.zeros((50, 60), np.uint8)
    b = np.zeros((60, 40, 3), np.float32)
    img = visualize.draw_matches(a, b, _match())
    assert img.shape == (60, 100, 3) and img.dtype == np.uint8
    mid_in = img[10, 36]  # on the line from (10, 10) to (60 + 12, 10)
    assert mid_in[1] > 100 and mid_in[0] < 50
    mid_out = img[42, 47]  # on the line from (30, 40) to (65, 45)
    assert mid_out[0] > 100 and mid_out[1] < 50


def test_overlay_and_checkerboard():
    a = np.zeros((20, 30), np.uint8)
    b = np.full((20, 30, 3), 200, np.uint8)
    assert np.array_equal(visualize.overlay(a, b, 0.0), visualize.to_rgb_uint8(a))
    assert (visualize.overlay(a, b, 1.0) == 200).all()
    assert (visualize.overlay(a, b, 0.5) == 100).all()
    cb = visualize.checkerboard(a, b, tiles=3)
    assert cb.shape == (20, 30, 3)
    assert (cb[0, 0] == 0).all() and (cb[0, 12] == 200).all() and (cb[12, 12] == 0).all()
    with pytest.raises(InputError, match="size"):
        visualize.overlay(a, b[:5])
    with pytest.raises(InputError, match="alpha"):
        visualize.overlay(a, b, 2.0)
    with pytest.raises(InputError, match="tiles"):
        visualize.checkerboard(a, b, tiles=0)


def test_to_rgb_uint8_conversions():
    assert visualize.to_rgb_uint8(np.full((2, 2), 65535, np.uint16)).max() == 255
    assert visualize.to_rgb_uint8(np.ones((2, 2), bool)).max() == 255
    assert visualize.to_rgb_uint8(np.zeros((2, 2, 4), np.uint8)).shape == (2, 2, 3)
    with pytest.raises(InputError, match="image"):
        visualize.to_rgb_uint8(np.zeros((0, 2)))


def test_pictures_of_12_bit_and_float_data_use_the_features_stretch():
    """12-bit data in uint16 (0-4000) is shown over the full grey range, as the matcher sees it, not as a
    dark picture (4000 / 257 = 16 grey levels); a float image in any range likewise."""
    from reglib.features import to_gray_uint8

    ramp = np.linspace(0, 4000, 64 * 48).reshape(48, 64).astype(np.uint16)
    shown = visualize.to_rgb_uint8(ramp)
    assert shown.shape == (48, 64, 3) and shown.min() == 0 and shown.max() == 255
    assert np.abs(shown[:, :, 0].astype(int) - to_gray_uint8(ramp)).max() <= 1
    hounsfield = ramp.astype(np.float32) - 1000.0
    assert np.array_equal(visualize.to_rgb_uint8(hounsfield), shown)
    rgb = np.dstack([ramp, ramp // 2, ramp // 4])  # one range for all bands: the colour balance is kept
    pic = visualize.to_rgb_uint8(rgb).astype(int)
    assert pic[..., 0].max() == 255 and abs(pic[..., 1].max() - 128) <= 2 and abs(pic[..., 2].max() - 64) <= 2
