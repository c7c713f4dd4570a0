"""Splitting a loop of OpenCV calls over threads, as many as OpenCV itself may use.

OpenCV releases the GIL inside its calls, so a loop of many small ones (the dense stage's
template matching: thousands of calls of 10-50 us) runs on several cores from a few threads.
The thread count follows ``cv2.getNumThreads()`` (at most :data:`MAX_THREADS`): a worker
process that set OpenCV to one thread (:func:`reglib.worker.prepare_worker_process`, the
service pool, batch jobs) runs the loop in its own thread, as before.
"""
from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import cv2

__all__ = ["MAX_THREADS", "split_range"]

MAX_THREADS = 4  # beyond this the Python side of the loop (slicing, the GIL) limits the gain
_MIN_PER_THREAD = 128  # iterations per thread at least (a handful would cost more than they gain)
_pools: dict[int, ThreadPoolExecutor] = {}


def _forget_pools() -> None:  # a forked child has the executors but not their threads
    _pools.clear()


os.register_at_fork(after_in_child=_forget_pools)


def split_range(n: int, run: Callable[[int, int], None]) -> None:
    """Call ``run(lo, hi)`` on contiguous parts of ``range(n)`` covering it, in parallel threads.

    ``run`` must write only to its own part of any shared output. Exceptions propagate.
    """
    threads = min(MAX_THREADS, max(1, cv2.getNumThreads()), os.cpu_count() or 1, n // _MIN_PER_THREAD)
    if threads <= 1:
        run(0, n)
        return
    pool = _pools.get(threads)
    if pool is None:
        pool = _pools[threads] = ThreadPoolExecutor(threads, thread_name_prefix="reglib-search")
    bounds = [n * k // threads for k in range(threads + 1)]
    for future in [pool.submit(run, lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])]:
        future.result()
