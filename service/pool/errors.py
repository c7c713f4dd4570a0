"""What the pool raises to its callers (each maps to one status in :mod:`service.problems`).

They pickle with their arguments, so a worker may raise them (``ComputeTimeout``,
``UndecodableImage``) and the server re-raises them unchanged.
"""
from __future__ import annotations

from typing import Any

from reglib.errors import InputError, ReglibError

__all__ = ["Overloaded", "NotReady", "ComputeTimeout", "UndecodableImage", "WorkerCrashed", "WorkerOutOfMemory"]


class Overloaded(ReglibError):
    """The work queue is full; ``retry_after`` is the ``Retry-After`` to answer with (seconds)."""

    def __init__(self, message: str, retry_after: int) -> None:
        super().__init__(message)
        self.retry_after = retry_after

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (str(self), self.retry_after))


class NotReady(Overloaded):
    """The pool is starting or stopping, or no worker can be started."""


class ComputeTimeout(ReglibError):
    """The request's wait plus compute time ran past the limit."""


class UndecodableImage(InputError):
    """An upload in an allowed format that cannot be decoded (corrupt or truncated)."""


class WorkerCrashed(ReglibError):
    """The request's job killed its worker process twice, on two fresh workers."""


class WorkerOutOfMemory(ReglibError):
    """The request's job needed more memory than one worker may use (``REGLIB_WORKER_MAX_MEMORY``)."""


class _RemoteTraceback(Exception):
    """The worker-side traceback of a job's exception, chained as its ``__cause__`` for the logs."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return f"\n\"\"\"\n{self.text}\"\"\""
