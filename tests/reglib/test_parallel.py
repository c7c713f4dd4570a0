"""reglib._parallel: a loop split over threads covers its range once, follows OpenCV's thread
count, propagates errors; the dense search gives the same maps threaded or not."""
from __future__ import annotations

import os
import threading

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import KernelWarp
from reglib._parallel import run_both, split_range
from reglib.dense import guided_matches


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


def test_run_both_returns_both_in_order_threaded_or_not(opencv_threads):
    for n in (1, 2):
        opencv_threads(n)
        names = []

        def first(names=names) -> str:
            names.append(threading.current_thread().name)
            return "a"

        def second(names=names) -> int:
            names.append(threading.current_thread().name)
            return 2

        assert run_both(first, second) == ("a", 2)
        caller = threading.current_thread().name
        # one thread: both in the caller's; more: first in the helper thread
        assert (names.count(caller) == 2) == (n == 1 or (os.cpu_count() or 1) == 1)


def test_run_both_nested_and_failing(opencv_threads):
    opencv_threads(2)
    # run_both inside first (the helper thread) runs one after the other instead of waiting on itself
    assert run_both(lambda: run_both(lambda: 1, lambda: 2), lambda: 3) == ((1, 2), 3)

    def fail() -> None:
        raise ValueError("first failed")

    with pytest.raises(ValueError, match="first failed"):
        run_both(fail, lambda: 0)
    started, finished = threading.Event(), []

    def slow() -> None:
        import time

        started.set()
        time.sleep(0.05)
        finished.append(True)

    def fail_once_first_runs() -> None:
        started.wait(5)
        raise KeyError("second failed")

    with pytest.raises(KeyError):
        run_both(slow, fail_once_first_runs)
    assert finished  # the error went up after first had finished


@pytest.mark.parametrize("features", ["sift", "multimodal"])
def test_match_images_is_the_same_with_one_or_two_threads(features, opencv_threads):
    from reglib import match_images

    a = skimage.data.camera()[::2, ::2].copy()
    b = cv2.warpAffine(a, cv2.getRotationMatrix2D((128, 128), 8, 1.05), (256, 256))
    results = []
    for n in (1, 2):
        opencv_threads(n)
        results.append(match_images(a, b, rng=0, features=features))
    one, two = results
    assert len(one.src) > 20 and one.n_inliers > 10
    np.testing.assert_array_equal(one.src, two.src)
    np.testing.assert_array_equal(one.dst, two.dst)
    np.testing.assert_array_equal(one.inliers, two.inliers)
    assert one.transform.to_dict() == two.transform.to_dict()
