"""Tests of reglib.features._peaks: the parabola vertex and sub-pixel maxima."""
from __future__ import annotations

import numpy as np
import pytest

from reglib.features import parabola_vertex, subpixel_peaks


@pytest.mark.parametrize("vertex", [-0.45, -0.2, 0.0, 0.125, 0.37])
def test_parabola_vertex_recovers_a_known_vertex(vertex):
    x = np.array([-1.0, 0.0, 1.0])
    for curvature, top in [(1.0, 0.0), (3.5, 10.0)]:
        y = top - curvature * (x - vertex) ** 2
        assert float(parabola_vertex(y[0], y[1], y[2])) == pytest.approx(vertex, abs=1e-12)


def test_parabola_vertex_is_vectorized_and_keeps_the_dtype():
    v = np.array([0.3, -0.1, 0.0], np.float32)
    x = np.array([-1.0, 0.0, 1.0], np.float32)[:, None]
    y = -((x - v) ** 2)
    out = parabola_vertex(y[0], y[1], y[2])
    assert out.dtype == np.float32 and out.shape == (3,)
    np.testing.assert_allclose(out, v, atol=1e-6)


def test_parabola_vertex_clips_and_refuses_flat_or_upward_parabolas():
    assert float(parabola_vertex(0.0, 1.0, 5.0)) == 0.0      # opens upwards: no maximum
    assert float(parabola_vertex(2.0, 2.0, 2.0)) == 0.0      # flat
    assert float(parabola_vertex(0.0, 1.0, 0.99)) < 0.5
    assert float(parabola_vertex(0.0, 1.0, 1.0)) == 0.5      # the vertex halfway: the clip's edge
    assert float(parabola_vertex(0.0, 1.0, 1.2)) == 0.5      # the neighbour is higher: clipped
    assert float(parabola_vertex(0.0, 1.0, 0.999999, min_curvature=1.5)) == 0.0  # curvature 1.0 < 1.5


def test_subpixel_peaks_of_a_sampled_paraboloid():
    yy, xx = np.mgrid[0:20, 0:30].astype(np.float64)
    peaks = [(7.3, 4.8), (21.6, 14.1)]  # (x, y)
    resp = np.maximum.reduce([5.0 - 0.5 * ((xx - x) ** 2 + (yy - y) ** 2) for x, y in peaks])
    rc = np.array([[round(y), round(x)] for x, y in peaks])
    out = subpixel_peaks(resp, rc)
    assert out.dtype == np.float64 and out.shape == (2, 2)
    np.testing.assert_allclose(out, peaks, atol=1e-9)
    assert subpixel_peaks(resp, np.zeros((0, 2), np.intp)).shape == (0, 2)
    # at the border the missing neighbour is the maximum itself: the vertex goes half a pixel out
    edge = subpixel_peaks(-((xx - 0.2) ** 2), np.array([[5, 0]]))
    assert edge.tolist() == [[-0.5, 5.0]]
