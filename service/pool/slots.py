"""The supervisor's records: :class:`_Job` for each admitted request, :class:`_Slot` for each of the
N worker places; and the two process helpers the supervisor needs (environment, exit status)."""
from __future__ import annotations

import asyncio
import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing.connection import Connection
from typing import Any


@contextmanager
def _environ(**values: str) -> Iterator[None]:
    """Set environment variables for the duration of the block (a spawned child copies them as it starts)."""
    previous = {key: os.environ.get(key) for key in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in previous.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _exit_text(exitcode: int | None) -> str:
    """A process's ``exitcode`` in words for the logs ("killed by SIGKILL", "exit status 1")."""
    if exitcode is None:
        return "exit status unknown"
    if exitcode < 0:
        try:
            return f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    return f"exit status {exitcode}"


class _Job:
    """One admitted request: ``fn(*args)``, its wall-clock ``deadline`` (``time.time()``) and the future its
    caller awaits. ``attempts`` counts the workers it ran on (a crash retries it once); ``finished`` is set
    once it no longer counts as pending; ``timed_out`` tells its slot that the caller has had its 504."""

    __slots__ = ("fn", "args", "deadline", "future", "request_id", "attempts", "finished", "timed_out")

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...], deadline: float, future: asyncio.Future[Any],
                 request_id: str | None) -> None:
        self.fn, self.args, self.deadline, self.future, self.request_id = fn, args, deadline, future, request_id
        self.attempts = 0
        self.finished = False
        self.timed_out = asyncio.Event()


class _Slot:
    """One of the pool's N places: the worker process in it now (none while it is being replaced), its
    pipe, and the job it runs or carries over to the next worker."""

    __slots__ = ("index", "process", "conn", "pid", "alive", "exited", "job", "carry", "planned_exit", "failures")

    def __init__(self, index: int) -> None:
        self.index = index
        self.process: multiprocessing.process.BaseProcess | None = None
        self.conn: Connection | None = None
        self.pid: int | None = None
        self.alive = False
        self.exited = asyncio.Event()
        self.job: _Job | None = None           # the job its worker runs
        self.carry: _Job | None = None         # a job taken from the queue, to run on the fresh worker
        self.planned_exit: str | None = None   # why we stopped it ourselves (None: it died on its own)
        self.failures = 0                      # failed starts in a row
