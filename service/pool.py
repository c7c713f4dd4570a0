"""A bounded work queue in front of a process pool: compute never runs on the event loop.

At most ``workers + queue_size`` requests are admitted at once; one more is refused at once with
:class:`Overloaded` (429 + Retry-After) rather than queued without bound. Before :meth:`WorkPool.start`
has warmed every worker, while stopping, and after a worker died, requests get :class:`NotReady` (503).
A request that waits and computes longer than ``timeout`` gets :class:`ComputeTimeout` (504); a
process cannot be interrupted safely mid-computation, so its slot stays taken until the worker is
done (the bound stays true), and a job that was still queued at its deadline is skipped by the worker.

Workers are spawned (not forked: the server has threads), set ``cv2.setNumThreads(1)`` so N
workers use N cores, keep freed memory for the next request (:func:`reglib.prepare_worker_process`), and inherit
OpenCV's own pixel limit ``OPENCV_IO_MAX_IMAGE_PIXELS``.
"""
from __future__ import annotations

import asyncio
import logging
import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from reglib.errors import InputError, ReglibError

__all__ = ["WorkPool", "Overloaded", "NotReady", "ComputeTimeout", "UndecodableImage"]

log = logging.getLogger("service.pool")
T = TypeVar("T")


class Overloaded(ReglibError):
    """The work queue is full."""

    def __init__(self, message: str, retry_after: int) -> None:
        super().__init__(message)
        self.retry_after = retry_after

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (str(self), self.retry_after))


class NotReady(Overloaded):
    """The pool is starting, stopping or restarting."""


class ComputeTimeout(ReglibError):
    """The request's wait plus compute time ran past the limit."""


class UndecodableImage(InputError):
    """An upload in an allowed format that cannot be decoded (corrupt or truncated)."""


def _init_worker() -> None:
    from reglib import prepare_worker_process

    prepare_worker_process()
    import reglib  # noqa: F401  - import the library once per worker, not on the first request


def _ping() -> int:
    return os.getpid()


def _run_before(deadline: float, fn: Callable[..., T], *args: Any) -> T:
    if time.time() > deadline:  # waited in the queue past the limit: the caller has had its 504
        raise ComputeTimeout("skipped: the request's time limit passed while it was queued")
    return fn(*args)


class WorkPool:
    """``workers`` processes behind a queue of ``queue_size`` waiting requests."""

    def __init__(self, *, workers: int, queue_size: int, timeout: float, retry_after: int,
                 opencv_max_pixels: int, on_change: Callable[[int, int], None] | None = None) -> None:
        self.workers = workers
        self.capacity = workers + queue_size
        self.timeout = timeout
        self.retry_after = retry_after
        self.opencv_max_pixels = opencv_max_pixels
        self._on_change = on_change
        self._executor: ProcessPoolExecutor | None = None
        self._pending = 0
        self._ready = False
        self._restarting: asyncio.Task[None] | None = None

    @property
    def ready(self) -> bool:
        return self._ready

    @property
    def pending(self) -> int:
        """Admitted requests not yet finished (running and queued)."""
        return self._pending

    async def start(self) -> None:
        """Spawn the workers and wait until every one has imported reglib; then the pool is ready."""
        loop = asyncio.get_running_loop()
        executor = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                       initializer=_init_worker)
        self._executor = executor
        # Spawned children copy the environment when they start; OpenCV reads its limit there. The
        # server's own environment is restored once they all run (one ping each spawns them all).
        key, previous = "OPENCV_IO_MAX_IMAGE_PIXELS", os.environ.get("OPENCV_IO_MAX_IMAGE_PIXELS")
        os.environ[key] = str(self.opencv_max_pixels)
        try:
            await asyncio.gather(*(asyncio.wrap_future(executor.submit(_ping), loop=loop)
                                   for _ in range(self.workers)))
        finally:
            if previous is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = previous
        self._ready = True
        log.info("work pool ready: %d workers, queue %d", self.workers, self.capacity - self.workers)

    async def stop(self) -> None:
        """Refuse new work, cancel what is queued, and wait for the workers to exit."""
        self._ready = False
        if self._restarting is not None:
            self._restarting.cancel()
        executor, self._executor = self._executor, None
        if executor is not None:
            await asyncio.to_thread(executor.shutdown, wait=True, cancel_futures=True)

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn(*args)`` in a worker and return its result (its exception is raised here).

        Raises
        ------
        NotReady, Overloaded, ComputeTimeout
            As described in the module docstring; anything ``fn`` raises is re-raised.
        """
        executor = self._executor
        if not self._ready or executor is None:
            raise NotReady("the compute pool is not ready; retry shortly", self.retry_after)
        if self._pending >= self.capacity:
            raise Overloaded(f"all {self.workers} workers are busy and {self.capacity - self.workers} requests "
                             "are waiting; retry shortly", self.retry_after)
        deadline = time.time() + self.timeout
        try:
            future: Future[T] = executor.submit(_run_before, deadline, fn, *args)
        except (BrokenProcessPool, RuntimeError):
            self._broken()
            raise NotReady("the compute pool is restarting; retry shortly", self.retry_after) from None
        self._pending += 1
        self._changed()
        loop = asyncio.get_running_loop()
        future.add_done_callback(lambda _: loop.call_soon_threadsafe(self._release))
        try:
            return await asyncio.wait_for(asyncio.shield(asyncio.wrap_future(future, loop=loop)), self.timeout)
        except TimeoutError:
            future.cancel()
            raise ComputeTimeout(f"the computation did not finish within {self.timeout:g} s") from None
        except BrokenProcessPool:
            self._broken()
            raise NotReady("a worker process died; the compute pool is restarting", self.retry_after) from None

    def _release(self) -> None:
        self._pending -= 1
        self._changed()

    def _changed(self) -> None:
        if self._on_change is not None:
            running = min(self._pending, self.workers)
            self._on_change(running, self._pending - running)

    def _broken(self) -> None:
        if self._restarting is None or self._restarting.done():
            self._ready = False
            self._restarting = asyncio.get_running_loop().create_task(self._restart())

    async def _restart(self) -> None:
        log.error("a worker process died; restarting the pool")
        old, self._executor = self._executor, None
        if old is not None:
            await asyncio.to_thread(old.shutdown, wait=False, cancel_futures=True)
        await self.start()
