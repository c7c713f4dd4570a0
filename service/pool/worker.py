"""The worker process, and both ends of the pipe it answers on.

A worker is spawned with one end of a duplex pipe (:func:`worker_main`). It imports reglib and
warms up, caps its own address space, sends ``("ready", pid, limit)``, then answers one message at
a time: a job ``(deadline, fn, args)`` gets ``("ok", result)``, ``("err", exception, traceback
text)`` or ``("oom", text)``; ``None`` (or the pipe closing) makes it exit. The server's half is
:func:`await_ready` and :func:`roundtrip`: blocking calls, run on threads next to the event loop,
that also watch the process's sentinel so a worker that dies is noticed instead of waited for.
"""
from __future__ import annotations

import os
import signal
import time
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection
from multiprocessing.connection import wait as wait_for_any
from typing import Any

from .errors import ComputeTimeout

__all__ = ["worker_main", "await_ready", "roundtrip", "crash_worker", "DIED"]

#: What :func:`roundtrip` returns when the worker exited before it answered.
DIED = ("died",)


def _prepare() -> None:
    """Import reglib and set the process up for compute (:func:`reglib.worker.prepare_worker_process`)."""
    from reglib.worker import prepare_worker_process  # imports the library once per worker, not on the first request

    prepare_worker_process()


def _address_space() -> int:
    """This process's virtual size in bytes, from ``/proc/self/statm``."""
    with open("/proc/self/statm", encoding="ascii") as f:
        return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def _cap_address_space(max_memory: int) -> int:
    """Set RLIMIT_AS to this process's size now plus ``max_memory``; returns the limit (0: none set)."""
    if max_memory <= 0:
        return 0
    import resource

    try:
        limit = _address_space() + max_memory
    except OSError:  # no /proc: no cap rather than a wrong one
        return 0
    _soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    return limit


def _is_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is an allocation failing at the cap (``MemoryError``, or OpenCV's ``StsNoMem``)."""
    if isinstance(exc, MemoryError):
        return True
    # cv2.error with code -4 (StsNoMem): "Insufficient memory ... Failed to allocate N bytes"
    return type(exc).__module__.startswith("cv2") and (getattr(exc, "code", None) == -4
                                                       or "Insufficient memory" in str(exc))


def crash_worker() -> None:
    """The job a fault-injected request runs instead of its own: the worker SIGKILLs itself."""
    os.kill(os.getpid(), signal.SIGKILL)


def _call(deadline: float, fn: Callable[..., Any], args: tuple[Any, ...]) -> tuple[Any, ...]:
    """Run one job and return its reply message (``ok``, ``err`` or ``oom``); never raises."""
    if time.time() > deadline:  # waited in the pipe past the limit: the caller has had its 504
        return ("err", ComputeTimeout("skipped: the request's time limit passed while it was queued"), "")
    try:
        return ("ok", fn(*args))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the caller
        if _is_out_of_memory(exc):
            return ("oom", f"{type(exc).__name__}: {str(exc)[:300]}")
        return ("err", exc, traceback.format_exc())


def worker_main(conn: Connection, max_memory: int) -> None:
    """One worker: warm up, cap the address space, then answer one job at a time until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _prepare()
    limit = _cap_address_space(max_memory)
    conn.send(("ready", os.getpid(), limit))
    while True:
        try:
            message = conn.recv()
        except EOFError:  # the server is gone
            return
        except MemoryError:  # the job's own arguments are over the cap; the pipe is mid-message now
            conn.send(("oom", "the request's data alone is over the worker memory limit"))
            return
        if message is None:
            return
        reply = _call(*message)
        try:
            conn.send(reply)
        except OSError:  # the server is gone
            return
        except MemoryError:
            conn.send(("oom", "the answer is over the worker memory limit"))
        except Exception as exc:  # noqa: BLE001 - an exception or result that does not pickle
            conn.send(("err", RuntimeError(f"the job's outcome cannot be sent back: {type(exc).__name__}: {exc}"),
                       traceback.format_exc()))


def await_ready(conn: Connection, sentinel: int, timeout: float) -> tuple[Any, ...] | None:
    """Blocking: the worker's ready message, or None if it exited or stayed silent past ``timeout``."""
    try:
        if conn in wait_for_any([conn, sentinel], timeout):
            reply = conn.recv()
            return reply if isinstance(reply, tuple) and reply and reply[0] == "ready" else None
    except (EOFError, OSError):
        pass
    return None


def roundtrip(conn: Connection, sentinel: int, message: tuple[Any, ...]) -> tuple[Any, ...]:
    """Blocking: send one job and return the worker's reply, or :data:`DIED` if the worker exits first."""
    try:
        conn.send(message)
    except OSError:  # it died, or stopped reading (its reply, if any, is still readable)
        pass
    try:
        if conn in wait_for_any([conn, sentinel]):
            reply: tuple[Any, ...] = conn.recv()
            return reply
    except (EOFError, OSError):
        pass
    except Exception as exc:  # noqa: BLE001 - a reply that does not unpickle here
        return ("err", RuntimeError(f"the job's outcome cannot be read back: {type(exc).__name__}: {exc}"), "")
    return DIED

