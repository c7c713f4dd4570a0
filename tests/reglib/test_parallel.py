"""reglib._parallel: a loop split over threads covers its range once, follows OpenCV's thread
count, propagates errors; the dense search gives the same maps threaded or not."""
from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import KernelWarp
from reglib._parallel import split_range
from reglib.refine import guided_matches


@pytest.fixture
def opencv_threads():
    before = cv2.getNumThreads()

    def set_to(n: int) -> None:
        cv2.setNumThreads(n)

    yield set_to
    cv2.setNumThreads(before)


@pytest.mark.parametrize("n", [0, 1, 127, 128, 255, 256, 1001])
def test_split_range_covers_the_range_once(n, opencv_threads):
    opencv_threads(4)
    hits = np.zeros(n, int)
    names = set()

    def run(lo: int, hi: int) -> None:
        names.add(threading.current_thread().name)
        hits[lo:hi] += 1

    split_range(n, run)
    assert (hits == 1).all()
    # below two threads' worth of work (128 each) it runs in the caller's thread
    if n < 256:
        assert names == {threading.current_thread().name}


def test_split_range_follows_opencv_threads_and_propagates_errors(opencv_threads):
    opencv_threads(1)
    names = set()
    split_range(5000, lambda lo, hi: names.add(threading.current_thread().name))
    assert names == {threading.current_thread().name}
    opencv_threads(2)

    def fail(lo: int, hi: int) -> None:
        if lo > 0:
            raise ValueError("part failed")

    with pytest.raises(ValueError, match="part failed"):
        split_range(5000, fail)


def test_dense_search_is_the_same_threaded_or_not(opencv_threads):
    a = skimage.data.camera().astype(np.float32)
    b = np.roll(a, (2, -3), axis=(0, 1))
    f0 = KernelWarp.identity(2)
    out = []
    for threads in (1, 2):
        opencv_threads(threads)
        out.append(guided_matches(a, b, f0, step=8, radius=6))
    (src1, dst1, ncc1), (src2, dst2, ncc2) = out
    assert len(src1) > 500
    assert np.array_equal(src1, src2) and np.array_equal(dst1, dst2) and np.array_equal(ncc1, ncc2)
    # and it found the shift
    assert np.median(dst1 - src1, axis=0) == pytest.approx([-3.0, 2.0], abs=0.05)
