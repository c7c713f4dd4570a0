"""Where batch work runs: local worker processes, or a Dask distributed cluster, behind one interface.

An executor maps a picklable function over picklable tasks and yields ``(task, result)`` pairs in
completion order, where ``result`` is the function's return value or the exception it ended with.
Tasks carry file paths, never image arrays: on a cluster every worker reads the images itself.
A worker process that dies (killed, out of memory, a crash in native code) costs the tasks it was
running one attempt each; a task is retried up to ``retries`` times before it comes back as
:class:`WorkerLost`.
"""
from __future__ import annotations

import abc
import contextlib
import multiprocessing
import os
import signal
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import resource_tracker
from typing import Any, TypeVar

from ..errors import InputError, ReglibError

__all__ = ["Executor", "LocalExecutor", "DaskExecutor", "ExecutorStartError", "WorkerLost"]

T = TypeVar("T")


def _count(name: str, value: object, low: int) -> int:
    """``value`` if it is an int >= ``low`` (0 or 1), else an ``InputError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InputError(f"`{name}` must be a {'positive' if low else 'non-negative'} integer, got {value!r}")
    return value


class WorkerLost(ReglibError):
    """The worker process running a task died, on every allowed attempt."""


class ExecutorStartError(ReglibError):
    """The executor could not get its workers (e.g. no scheduler at the address, a worker that cannot start)."""


class Executor(abc.ABC):
    """Runs tasks somewhere; use as a context manager so its workers are always released."""

    def __enter__(self) -> Executor:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc_info: object) -> None:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
            self.interrupt()
        self.close()

    def start(self) -> None:  # noqa: B027 - optional hook
        """Acquire the workers (called by ``__enter__``)."""

    def interrupt(self) -> None:  # noqa: B027 - optional hook
        """Stop the running tasks now (Ctrl-C; called by ``__exit__`` before :meth:`close`): once it returns,
        no task of this executor writes anything more."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the workers; safe to call twice."""

    @abc.abstractmethod
    def map_unordered(self, fn: Callable[[T], Any], tasks: Iterable[T]) -> Iterator[tuple[T, Any]]:
        """Yield ``(task, fn(task) or the exception it raised)`` as tasks finish, in any order."""

    @abc.abstractmethod
    def describe(self) -> str:
        """A short human description, e.g. ``local processes x 2``."""


def _start_worker() -> None:
    """In a local worker: leave Ctrl-C to the job process (it stops the workers itself, so the terminal gets
    one line, not a traceback from every worker), and exit when the job process is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # spawned with SIGINT held back (_sigint_held): a pending one is dropped
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    _watch_parent()


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """SIGINT held back (blocked) in this thread while it spawns workers.

    A spawned worker inherits the block, so a Ctrl-C that reaches it while it is still starting up (importing,
    before :func:`_start_worker` ignores SIGINT) stays pending and is then dropped, instead of printing a
    traceback. Here a Ctrl-C is delivered as soon as the block ends.
    """
    if not hasattr(signal, "pthread_sigmask"):  # (Windows: no signal masks, and no process groups to signal)
        yield
        return
    # Spawning starts multiprocessing's resource tracker first if it is not running, and that unblocks SIGINT
    # in this thread when it is done (it holds its own signals back the same way): start it before the block.
    resource_tracker.ensure_running()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _watch_parent() -> None:
    """In a local worker: exit as soon as the job process is gone (e.g. killed with SIGKILL).

    Without this, workers of a killed job would finish their current pair and then wait forever
    on a queue nobody writes to, racing a resumed job for the same output folders.
    """
    import threading
    from multiprocessing.connection import wait as wait_for

    parent = multiprocessing.parent_process()
    if parent is None:  # pragma: no cover - only ever run inside a worker
        return

    def watch() -> None:
        wait_for([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="reglib-parent-watch", daemon=True).start()


# What Dask's nanny sets for its workers (distributed.nanny.pre-spawn-environ): one BLAS / OpenMP thread
# per process, since parallelism comes from the processes. Local workers get the same, so both executors
# compute the same floating-point sums in the same order and give the same answers.
WORKER_ENVIRON = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


class LocalExecutor(Executor):
    """Worker processes on this machine (``concurrent.futures.ProcessPoolExecutor``, spawn start).

    Workers run OpenCV and BLAS single-threaded (see ``WORKER_ENVIRON``); they exit by themselves
    when the job process dies.

    Parameters
    ----------
    workers : int, optional
        Number of processes; default ``os.cpu_count()``.
    retries : int
        Extra attempts for a task whose worker process died while it was running.
    """

    def __init__(self, workers: int | None = None, *, retries: int = 2):
        self.workers = _count("workers", (os.cpu_count() or 1) if workers is None else workers, 1)
        self.retries = _count("retries", retries, 0)
        self._pool: ProcessPoolExecutor | None = None
        self._saved_environ: dict[str, str | None] | None = None

    def describe(self) -> str:
        return f"local processes x {self.workers}"

    def _new_pool(self) -> ProcessPoolExecutor:
        # spawn, not fork: the job process may hold threads (progress bar, OpenCV) that fork would copy mid-state.
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_start_worker)

    def start(self) -> None:
        # Spawned workers inherit the environment at the time they start, which may be any submit (a
        # broken pool is replaced), so the worker settings stay in place until close().
        if self._saved_environ is None:
            self._saved_environ = {name: os.environ.get(name) for name in WORKER_ENVIRON}
            os.environ.update(WORKER_ENVIRON)
        if self._pool is None:
            self._pool = self._new_pool()

    def interrupt(self) -> None:
        """Cancel the queued pairs and end the workers; a pair cut off leaves only a hidden ``.partial`` folder
        (removed by the next run), never a half-written one under its id."""
        if self._pool is None:
            return
        processes = list((getattr(self._pool, "_processes", None) or {}).values())  # (no public accessor)
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join(timeout=10)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._saved_environ is not None:
            for name, value in self._saved_environ.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
            self._saved_environ = None

    def map_unordered(self, fn: Callable[[T], Any], tasks: Iterable[T]) -> Iterator[tuple[T, Any]]:
        self.start()
        items = list(tasks)
        queue = deque(range(len(items)))
        attempts = [0] * len(items)
        running: dict[Future[Any], int] = {}
        window = 2 * self.workers  # keeps every worker busy without queueing the whole job up front
        while queue or running:
            pool = self._pool or self._new_pool()
            self._pool = pool
            with _sigint_held():  # a submit may spawn a worker
                while queue and len(running) < window:
                    index = queue.popleft()
                    running[pool.submit(fn, items[index])] = index
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            lost: list[int] = []
            for future in done:
                index = running.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool:
                    lost.append(index)
                    continue
                except Exception as exc:  # the task's own failure: reported, not retried
                    result = exc
                yield items[index], result
            if lost:
                # A dead worker breaks the whole pool: every task still in it is lost with it. We cannot
                # tell which one killed it, so each pays one attempt.
                lost.extend(running.values())
                running.clear()
                pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None
                for index in lost:
                    attempts[index] += 1
                    if attempts[index] > self.retries:
                        yield items[index], WorkerLost(
                            f"the worker process died while running this task ({attempts[index]} attempt(s))")
                    else:
                        queue.appendleft(index)


class DaskExecutor(Executor):
    """Tasks on a Dask distributed cluster: an existing scheduler, or a LocalCluster started here.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler, e.g. ``tcp://host:8786``. Workers must be able to import
        reglib and read the image paths and the output folder (a shared file system).
    local_workers : int, optional
        Start a LocalCluster of this many worker processes, one thread each (when no ``scheduler``).
    retries : int
        For a LocalCluster: how many worker deaths a task may be part of before it is reported as
        lost (Dask's ``distributed.scheduler.allowed-failures``); a remote scheduler uses its own setting.
    """

    def __init__(self, scheduler: str | None = None, *, local_workers: int | None = None, retries: int = 2):
        if (scheduler is None) == (local_workers is None):
            raise InputError("give exactly one of `scheduler` (an address) and `local_workers` (a count)")
        self.scheduler = scheduler
        self.local_workers = None if local_workers is None else _count("local_workers", local_workers, 1)
        self.retries = _count("retries", retries, 0)
        self._client: Any = None
        self._cluster: Any = None

    def describe(self) -> str:
        if self.scheduler is not None:
            return f"dask scheduler {self.scheduler}"
        return f"dask LocalCluster x {self.local_workers}"

    def start(self) -> None:
        if self._client is not None:
            return
        try:
            import dask
            from distributed import Client, LocalCluster
        except ImportError:
            raise InputError("the Dask executor needs dask[distributed]: pip install 'reglib[dask]'") from None
        try:
            if self.scheduler is not None:
                self._client = Client(self.scheduler)
                return
            with dask.config.set({"distributed.scheduler.allowed-failures": self.retries}):
                self._cluster = LocalCluster(n_workers=self.local_workers, threads_per_worker=1, processes=True,
                                             dashboard_address=None)
            self._client = Client(self._cluster)
        except Exception as exc:  # Dask raises OSError, TimeoutError, RuntimeError, ... depending on the cause
            self.close()
            raise ExecutorStartError(f"the {self.describe()} could not start: {type(exc).__name__}: {exc}") from exc

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def map_unordered(self, fn: Callable[[T], Any], tasks: Iterable[T]) -> Iterator[tuple[T, Any]]:
        from distributed import as_completed
        from distributed.scheduler import KilledWorker

        self.start()
        run = uuid.uuid4().hex[:8]
        futures = {}
        for number, task in enumerate(tasks):
            future = self._client.submit(fn, task, key=f"reglib-batch-{run}-{number}", pure=False)
            futures[future] = task
        for future in as_completed(futures):
            task = futures.pop(future)
            try:
                result: Any = future.result()
            except KilledWorker as exc:
                result = WorkerLost(f"the worker process died while running this task: {exc}")
            except Exception as exc:
                result = exc
            future.release()
            yield task, result
