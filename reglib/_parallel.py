"""Work split over threads, as many as OpenCV itself may use.

OpenCV, numpy and scipy.fft release the GIL inside their calls, so a loop of many small OpenCV
calls (the dense stage's template matching: thousands of calls of 10-50 us) runs on several cores
from a few threads (:func:`split_range`), and so does the same work on both images of a pair
(features, structure fields: :func:`run_both`).
The thread count follows ``cv2.getNumThreads()`` (at most :data:`MAX_THREADS`): a worker
process that set OpenCV to one thread (:func:`reglib.worker.prepare_worker_process`, the
service pool, batch jobs) runs the loop in its own thread, as before.
"""
from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import cv2

__all__ = ["MAX_THREADS", "run_both", "split_range"]

A = TypeVar("A")
B = TypeVar("B")

MAX_THREADS = 4  # beyond this the Python side of the loop (slicing, the GIL) limits the gain
_MIN_PER_THREAD = 128  # iterations per thread at least (a handful would cost more than they gain)
_pools: dict[int, ThreadPoolExecutor] = {}
# run_both's second thread: an executor of its own, so that work it runs may call split_range
# (whose pool threads could otherwise all be waiting on their own parts)
_pair: list[ThreadPoolExecutor] = []
_PAIR_NAME = "reglib-pair"


def _forget_pools() -> None:  # a forked child has the executors but not their threads
    _pools.clear()
    _pair.clear()


os.register_at_fork(after_in_child=_forget_pools)


def _allowed_threads() -> int:
    """Threads the work may use: as many as OpenCV may (at least 1), no more than cores or MAX_THREADS."""
    return min(MAX_THREADS, max(1, cv2.getNumThreads()), os.cpu_count() or 1)


def run_both(first: Callable[[], A], second: Callable[[], B]) -> tuple[A, B]:
    """``(first(), second())``, the two run at once when OpenCV may use more than one thread.

    For two independent pieces of work of similar size that spend their time in calls that
    release the GIL (numpy, scipy.fft, OpenCV), e.g. the same features of both images. ``first``
    runs in a helper thread, ``second`` in the caller's. Exceptions propagate (after both have
    finished).
    """
    # (in the helper thread itself, e.g. run_both inside first: one after the other, or it would
    # wait for itself)
    if _allowed_threads() <= 1 or threading.current_thread().name.startswith(_PAIR_NAME):
        return first(), second()
    if not _pair:
        _pair.append(ThreadPoolExecutor(1, thread_name_prefix=_PAIR_NAME))
    future = _pair[0].submit(first)
    try:
        b = second()
    except BaseException:
        if not future.cancel():
            future.exception()  # first finishes before the error goes up
        raise
    return future.result(), b


def split_range(n: int, run: Callable[[int, int], None]) -> None:
    """Call ``run(lo, hi)`` on contiguous parts of ``range(n)`` covering it, in parallel threads.

    ``run`` must write only to its own part of any shared output. Exceptions propagate.
    """
    threads = min(_allowed_threads(), n // _MIN_PER_THREAD)
    if threads <= 1:
        run(0, n)
        return
    pool = _pools.get(threads)
    if pool is None:
        pool = _pools[threads] = ThreadPoolExecutor(threads, thread_name_prefix="reglib-search")
    bounds = [n * k // threads for k in range(threads + 1)]
    for future in [pool.submit(run, lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]:
        future.result()
