""":class:`WorkPool`: a bounded work queue in front of N supervised worker processes (see the package).

Admission. At most ``workers + queue_size`` requests are admitted at once; one more is refused at
once with :class:`Overloaded` (429 + Retry-After) rather than queued without bound. Before
:meth:`WorkPool.start` has warmed every worker and once :meth:`WorkPool.stop` has begun, requests get
:class:`NotReady` (503). A request that waits and computes longer than ``timeout`` gets
:class:`ComputeTimeout` (504): a job still queued at its deadline is dropped, and the worker of a job
still running at its deadline is killed and replaced (a process cannot be interrupted safely
mid-computation; killing it frees the slot, so the bound stays true).

Crash isolation. Each of the N slots is one spawned process with a pipe of its own (no shared
``ProcessPoolExecutor``, which breaks whole when one process dies). A slot's supervisor task sends
one job at a time and waits for its answer or the process's exit, whichever comes first; the exit is
also watched while the slot is idle (the process sentinel is on the event loop), so a dead worker is
noticed at once and replaced at once. A worker that dies fails nothing but the job it ran, and that
job is retried once on the fresh worker (every job is a pure function of its request); a job that
kills a worker twice raises :class:`WorkerCrashed` (500, logged with its request id). Other jobs,
running or queued, never see the crash. :attr:`WorkPool.ready` is False exactly while fewer workers
than configured are alive (and before start, and from stop on).

Memory cap. ``max_memory`` bytes (``REGLIB_WORKER_MAX_MEMORY``) is the address space a job may add to
an idle worker: each worker measures its own virtual size once warm (libraries imported, OpenBLAS
threads started) and sets ``RLIMIT_AS`` to that plus the cap, so allocations beyond it fail inside
the worker instead of growing until the host runs out. A job that hits the cap (``MemoryError``, or
OpenCV's ``Insufficient memory``) raises :class:`WorkerOutOfMemory` (413), and its worker is replaced
so the next job starts from a clean heap.

Workers are spawned (not forked: the server has threads), run
:func:`reglib.worker.prepare_worker_process` (OpenCV single-threaded so N workers use N cores, freed
memory kept for the next request), inherit OpenCV's own pixel limit ``OPENCV_IO_MAX_IMAGE_PIXELS``,
and ignore SIGINT and SIGTERM (a Ctrl-C in a terminal, or a service manager's stop, may reach the
whole process group; the server drains, then stops them itself, and kills them at exit if it could
not). A worker whose server is gone exits on its own when its pipe closes.
"""
from __future__ import annotations

import asyncio
import atexit
import contextvars
import logging
import multiprocessing
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from types import MappingProxyType
from typing import Any, TypeVar

from ..units import human_bytes
from .errors import ComputeTimeout, NotReady, Overloaded, WorkerCrashed, WorkerOutOfMemory, _RemoteTraceback
from .slots import _environ, _exit_text, _Job, _Slot
from .worker import DIED, await_ready, crash_worker, roundtrip, worker_main

__all__ = ["WorkPool", "CRASH_FAULT", "job_context"]

log = logging.getLogger("service.pool")
T = TypeVar("T")

#: The value of :data:`job_context`'s ``fault`` that makes a job kill its worker (fault-injection tests only).
CRASH_FAULT = "crash"

#: Per-request context read when a job is submitted: ``{"request_id": ..., "fault": ...}`` (set by the
#: request middleware, :mod:`service.request_id`; empty outside a request).
job_context: contextvars.ContextVar[Mapping[str, str]] = contextvars.ContextVar("reglib_job_context",
                                                                               default=MappingProxyType({}))

_START_TIMEOUT_S = 120.0   # spawn + import of reglib; far more than it takes on a loaded machine
_STOP_WAIT_S = 5.0         # how long stop() lets the running jobs finish before it kills their workers


class WorkPool:
    """``workers`` supervised processes behind a queue of ``queue_size`` waiting requests.

    Parameters
    ----------
    workers, queue_size : int
        Worker processes, and requests that may wait for one (see the module docstring).
    timeout : float
        Seconds one request may wait and compute (504 beyond).
    retry_after : int
        The ``Retry-After`` of 429 and 503.
    opencv_max_pixels : int
        ``OPENCV_IO_MAX_IMAGE_PIXELS`` of the workers.
    on_change : callable(running, queued), optional
        Called whenever the number of running or queued jobs changes.
    max_memory : int
        Bytes of address space a job may add to an idle worker (``RLIMIT_AS``); 0: no cap.
    on_workers : callable(alive), optional
        Called whenever the number of live workers changes.
    on_exit : callable(reason), optional
        Called once per worker that exits other than at stop: ``"crashed"``, ``"timeout"``, ``"memory"``.
    """

    def __init__(self, *, workers: int, queue_size: int, timeout: float, retry_after: int,
                 opencv_max_pixels: int, on_change: Callable[[int, int], None] | None = None,
                 max_memory: int = 0, on_workers: Callable[[int], None] | None = None,
                 on_exit: Callable[[str], None] | None = None) -> None:
        self.workers = workers
        self.capacity = workers + queue_size
        self.timeout = timeout
        self.retry_after = retry_after
        self.opencv_max_pixels = opencv_max_pixels
        self.max_memory = max_memory
        self._on_change = on_change
        self._on_workers = on_workers
        self._on_exit = on_exit
        self._slots: list[_Slot] = []
        self._tasks: list[asyncio.Task[None]] = []
        self._queue: asyncio.Queue[_Job] | None = None
        self._threads: ThreadPoolExecutor | None = None
        self._pending = 0
        self._accepting = False
        self._stopping = False
        self._idle: asyncio.Event | None = None

    # -- state -----------------------------------------------------------------------------------------

    @property
    def ready(self) -> bool:
        """Accepting work, with every configured worker alive."""
        return self._accepting and self.alive == self.workers

    @property
    def alive(self) -> int:
        """Workers started, warm and not (known to be) dead."""
        return sum(slot.alive for slot in self._slots)

    @property
    def pending(self) -> int:
        """Admitted requests not yet finished (running and queued)."""
        return self._pending

    @property
    def pids(self) -> list[int]:
        """Process ids of the live workers (for operators and fault tests)."""
        return [slot.pid for slot in self._slots if slot.alive and slot.pid is not None]

    # -- lifecycle -------------------------------------------------------------------------------------

    async def start(self) -> None:
        """Spawn the workers and wait until every one has imported reglib; then the pool is ready."""
        loop = asyncio.get_running_loop()
        self._stopping = False
        self._queue = asyncio.Queue()
        self._idle = asyncio.Event()
        self._idle.set()
        self._threads = ThreadPoolExecutor(max_workers=self.workers, thread_name_prefix="reglib-pool")
        self._slots = [_Slot(i) for i in range(self.workers)]
        try:
            outcomes = await asyncio.gather(*(self._spawn(slot) for slot in self._slots), return_exceptions=True)
        except BaseException:
            await self._kill_all()
            raise
        errors = [o for o in outcomes if isinstance(o, BaseException)]
        if errors:
            await self._kill_all()
            raise errors[0]
        self._tasks = [loop.create_task(self._supervise(slot), name=f"reglib-slot-{slot.index}")
                       for slot in self._slots]
        atexit.register(self._kill_now)
        self._accepting = True
        log.info("work pool ready: %d workers, queue %d, worker memory cap %s", self.workers,
                 self.capacity - self.workers, human_bytes(self.max_memory) if self.max_memory > 0 else "none")

    async def stop(self, wait: float = _STOP_WAIT_S) -> None:
        """Refuse new work, fail what is queued, give running jobs ``wait`` seconds, then stop the workers."""
        self._accepting = False
        if self._queue is None:
            return
        self._stopping = True
        while not self._queue.empty():
            self._fail(self._queue.get_nowait(), NotReady("the service is stopping; retry shortly", self.retry_after))
        if self._idle is not None and any(slot.job is not None for slot in self._slots):
            try:
                await asyncio.wait_for(self._idle.wait(), wait)
            except TimeoutError:
                log.warning("stopping with %d jobs still running; their workers are killed",
                            sum(slot.job is not None for slot in self._slots))
        running = [job for slot in self._slots for job in (slot.job, slot.carry) if job is not None]
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        for job in running:
            self._fail(job, NotReady("the service stopped before this request finished", self.retry_after))
        await self._kill_all(gently=True)
        atexit.unregister(self._kill_now)
        if self._threads is not None:
            self._threads.shutdown(wait=False, cancel_futures=True)
            self._threads = None
        self._queue = None
        self._changed()

    # -- submitting ------------------------------------------------------------------------------------

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn(*args)`` in a worker and return its result (its exception is raised here).

        Raises
        ------
        NotReady, Overloaded, ComputeTimeout, WorkerCrashed, WorkerOutOfMemory
            As described in the module docstring; anything ``fn`` raises is re-raised.
        """
        queue = self._queue
        if not self._accepting or queue is None:
            raise NotReady("the compute pool is not ready; retry shortly", self.retry_after)
        if all(slot.failures > 0 and not slot.alive for slot in self._slots):
            raise NotReady("no compute worker can be started; retry later", self.retry_after)
        if self._pending >= self.capacity:
            raise Overloaded(f"all {self.workers} workers are busy and {self.capacity - self.workers} requests "
                             "are waiting; retry shortly", self.retry_after)
        context = job_context.get()
        if context.get("fault") == CRASH_FAULT:
            fn, args = crash_worker, ()  # type: ignore[assignment]  # the fault test's job: it never returns a T
        loop = asyncio.get_running_loop()
        job = _Job(fn, args, time.time() + self.timeout, loop.create_future(), context.get("request_id"))
        self._pending += 1
        queue.put_nowait(job)
        self._changed()
        try:
            return await asyncio.wait_for(asyncio.shield(job.future), self.timeout)
        except TimeoutError:
            job.future.cancel()
            if any(slot.job is job for slot in self._slots):
                job.timed_out.set()  # its slot kills the worker and starts a fresh one
            else:
                self._finish(job)    # queued, or waiting for a fresh worker: the slot drops it
            raise ComputeTimeout(f"the computation did not finish within {self.timeout:g} s") from None
        except asyncio.CancelledError:
            job.future.cancel()      # the caller left: a queued job is dropped, a running one finishes
            if not any(slot.job is job for slot in self._slots):
                self._finish(job)
            raise

    # -- supervision -----------------------------------------------------------------------------------

    async def _spawn(self, slot: _Slot) -> None:
        loop = asyncio.get_running_loop()
        ctx = multiprocessing.get_context("spawn")
        parent, child = ctx.Pipe(duplex=True)
        process = ctx.Process(target=worker_main, args=(child, self.max_memory), daemon=True,
                              name=f"reglib-worker-{slot.index}")
        # Spawned children copy the environment when they start; OpenCV reads its limit there.
        try:
            with _environ(OPENCV_IO_MAX_IMAGE_PIXELS=str(self.opencv_max_pixels)):
                process.start()
        except BaseException:
            parent.close()
            raise
        finally:
            child.close()
        try:
            assert self._threads is not None
            reply = await loop.run_in_executor(self._threads, await_ready, parent, process.sentinel,
                                               _START_TIMEOUT_S)
        except BaseException:
            process.kill()
            parent.close()
            raise
        if reply is None:
            process.kill()
            await loop.run_in_executor(self._threads, process.join, 5.0)
            parent.close()
            raise RuntimeError(f"worker {slot.index} did not start ({_exit_text(process.exitcode)})")
        slot.process, slot.conn, slot.pid = process, parent, int(reply[1])
        slot.planned_exit, slot.failures = None, 0
        slot.exited.clear()
        slot.alive = True
        loop.add_reader(process.sentinel, self._exited, slot)
        self._workers_changed()

    def _exited(self, slot: _Slot) -> None:
        """The event loop saw the worker's sentinel: the process is gone."""
        if slot.process is not None:
            asyncio.get_running_loop().remove_reader(slot.process.sentinel)
        if slot.alive:
            slot.alive = False
            self._workers_changed()
        slot.exited.set()

    def _kill(self, slot: _Slot, reason: str) -> None:
        slot.planned_exit = reason
        if slot.alive:
            slot.alive = False
            self._workers_changed()
        if slot.process is not None and slot.process.exitcode is None:
            slot.process.kill()

    async def _reap(self, slot: _Slot) -> None:
        """Wait for a dead (or killed) worker to be gone, log why, and release its pipe."""
        process = slot.process
        if process is None:
            return
        await slot.exited.wait()
        loop = asyncio.get_running_loop()
        assert self._threads is not None
        await loop.run_in_executor(self._threads, process.join, 5.0)
        reason = slot.planned_exit
        if reason is None:
            log.warning("worker %d (pid %s) died: %s; starting a fresh one", slot.index, slot.pid,
                        _exit_text(process.exitcode))
        if reason != "stopped" and self._on_exit is not None:
            self._on_exit(reason or "crashed")
        if slot.conn is not None:
            slot.conn.close()
        try:
            process.close()
        except ValueError:  # still running after 5 s: it was killed, so it will not be for long
            pass
        slot.process, slot.conn, slot.pid = None, None, None

    async def _supervise(self, slot: _Slot) -> None:
        """One slot: keep a worker alive and feed it one job at a time; nothing but stop() ends it."""
        while not self._stopping:
            try:
                await self._supervise_once(slot)
            except asyncio.CancelledError:
                raise
            except Exception:  # a fault of ours: never leave the slot unattended
                log.exception("the supervisor of worker %d failed; replacing the worker", slot.index)
                self._kill(slot, "crashed")
                await asyncio.sleep(1.0)

    async def _supervise_once(self, slot: _Slot) -> None:
        """Replace the worker if it is gone, else run the next job on it."""
        if not slot.alive:
            await self._reap(slot)
            try:
                await self._spawn(slot)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - keep trying, but not in a hot loop
                slot.failures += 1
                delay = min(30.0, 0.5 * 2 ** min(slot.failures, 6))
                log.error("%s; retrying in %.1f s", exc, delay)
                await asyncio.sleep(delay)
                return
        job = slot.carry if slot.carry is not None else await self._next(slot)
        slot.carry = None
        if job is None:
            return
        if not slot.alive:          # died while the job was being handed over: not the job's fault
            slot.carry = job
            return
        if job.future.done() or job.finished or time.time() > job.deadline:
            self._finish(job)       # its caller has gone or has had its 504
            return
        try:
            if await self._execute(slot, job):
                slot.carry = job    # retried once, on the fresh worker
        except asyncio.CancelledError:
            raise
        except Exception as exc:    # a fault of ours: fail this job, keep the slot serving
            log.exception("the supervisor of worker %d failed on a job", slot.index,
                          extra={"request_id": job.request_id})
            self._fail(job, exc)
            self._kill(slot, "crashed")

    async def _next(self, slot: _Slot) -> _Job | None:
        """The next queued job, or None when this slot's worker exits while it waits for one."""
        assert self._queue is not None
        get = asyncio.ensure_future(self._queue.get())
        exited = asyncio.ensure_future(slot.exited.wait())
        try:
            await asyncio.wait({get, exited}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            exited.cancel()
            if not get.done():
                get.cancel()
        if get.done() and not get.cancelled():
            return get.result()
        return None

    async def _execute(self, slot: _Slot, job: _Job) -> bool:
        """Run ``job`` on ``slot``'s worker; True when it must be retried on a fresh worker."""
        loop = asyncio.get_running_loop()
        assert slot.conn is not None and slot.process is not None and self._threads is not None
        slot.job = job
        job.attempts += 1
        self._idle_changed()
        self._changed()
        try:
            answer: asyncio.Future[Any] = loop.run_in_executor(
                self._threads, roundtrip, slot.conn, slot.process.sentinel, (job.deadline, job.fn, job.args))
            timed_out: asyncio.Future[Any] = asyncio.ensure_future(job.timed_out.wait())
            try:
                await asyncio.wait({answer, timed_out}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                timed_out.cancel()
            if not answer.done():     # the caller has had its 504: kill the worker, free the slot
                log.warning("worker %d (pid %s) still ran a job at its time limit; replacing it", slot.index,
                            slot.pid, extra={"request_id": job.request_id})
                self._kill(slot, "timeout")
                await answer
                self._finish(job)
                return False
            reply = answer.result()
            if reply is DIED:
                if slot.alive:           # now, not when the loop next sees the sentinel
                    slot.alive = False
                    self._workers_changed()
                await loop.run_in_executor(self._threads, slot.process.join, 1.0)  # for its exit status
                exit_text = _exit_text(slot.process.exitcode)
                if job.attempts < 2 and not self._stopping:
                    log.warning("worker %d (pid %s) died running a request (%s); retrying it once on a fresh "
                                "worker", slot.index, slot.pid, exit_text, extra={"request_id": job.request_id})
                    return True
                if self._stopping:
                    self._fail(job, NotReady("the service stopped before this request finished", self.retry_after))
                else:
                    log.error("the request crashed a worker twice (%s); answering 500", exit_text,
                              extra={"request_id": job.request_id})
                    self._fail(job, WorkerCrashed("the request crashed its worker process twice"))
                return False
            kind = reply[0]
            if kind == "ok":
                if not job.future.done():
                    job.future.set_result(reply[1])
                self._finish(job)
            elif kind == "oom":
                log.warning("a job went over the worker memory limit (%s); replacing worker %d", reply[1],
                            slot.index, extra={"request_id": job.request_id})
                self._kill(slot, "memory")
                self._fail(job, WorkerOutOfMemory(
                    f"the computation needed more memory than one worker may use ({human_bytes(self.max_memory)}); "
                    "send smaller images or fewer points"))
            else:
                exc = reply[1]
                if len(reply) > 2 and reply[2]:
                    exc.__cause__ = _RemoteTraceback(reply[2])
                self._fail(job, exc)
            return False
        finally:
            slot.job = None
            self._idle_changed()
            self._changed()

    async def _kill_all(self, gently: bool = False) -> None:
        """Stop every worker (a stop message first when ``gently``, SIGKILL after a short wait)."""
        loop = asyncio.get_running_loop()
        for slot in self._slots:
            if slot.process is None:
                continue
            slot.planned_exit = "stopped"
            if gently and slot.conn is not None and slot.process.exitcode is None:
                try:
                    slot.conn.send(None)
                except OSError:
                    pass
            else:
                slot.process.kill()
        deadline = time.monotonic() + 3.0
        for slot in self._slots:
            process = slot.process
            if process is None:
                continue
            while process.exitcode is None and time.monotonic() < deadline:
                await asyncio.sleep(0.02)
            if process.exitcode is None:
                process.kill()
                await loop.run_in_executor(None, process.join, 5.0)
            try:
                loop.remove_reader(process.sentinel)
            except (ValueError, OSError):
                pass
            if slot.alive:
                slot.alive = False
            if slot.conn is not None:
                slot.conn.close()
            try:
                process.close()
            except ValueError:
                pass
            slot.process, slot.conn, slot.pid = None, None, None
        self._workers_changed()

    def _kill_now(self) -> None:
        """At interpreter exit without :meth:`stop` (a forced stop): SIGKILL the workers, which ignore SIGTERM."""
        for slot in self._slots:
            try:
                if slot.process is not None and slot.process.exitcode is None:
                    slot.process.kill()
            except (ValueError, OSError):  # closed or already gone
                pass

    # -- bookkeeping -----------------------------------------------------------------------------------

    def _fail(self, job: _Job, exc: BaseException) -> None:
        if not job.future.done():
            job.future.set_exception(exc)
        self._finish(job)

    def _finish(self, job: _Job) -> None:
        if not job.finished:
            job.finished = True
            self._pending -= 1
            self._changed()

    def _idle_changed(self) -> None:
        if self._idle is not None:
            if any(slot.job is not None for slot in self._slots):
                self._idle.clear()
            else:
                self._idle.set()

    def _changed(self) -> None:
        if self._on_change is not None:
            running = sum(slot.job is not None for slot in self._slots)
            self._on_change(running, max(0, self._pending - running))

    def _workers_changed(self) -> None:
        if self._on_workers is not None:
            self._on_workers(self.alive)
