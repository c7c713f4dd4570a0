"""A bounded work queue in front of N supervised worker processes: compute never runs on the event loop.

Admission is bounded (429 when full, 503 before start and from stop on, 504 past the deadline),
each worker is supervised (a crash fails only its job, retried once on a fresh worker) and a job's
memory is capped (413); :mod:`.supervisor`'s docstring tells how.

The package: :mod:`.errors` (what callers see), :mod:`.worker` (the worker process and the pipe it
answers on), :mod:`.slots` (the supervisor's records) and :mod:`.supervisor` (:class:`WorkPool`:
admission, supervision, crash isolation, the memory cap).
"""
from __future__ import annotations

from .errors import ComputeTimeout, NotReady, Overloaded, UndecodableImage, WorkerCrashed, WorkerOutOfMemory
from .supervisor import CRASH_FAULT, WorkPool, job_context

__all__ = ["CRASH_FAULT", "ComputeTimeout", "NotReady", "Overloaded", "UndecodableImage", "WorkPool", "WorkerCrashed",
           "WorkerOutOfMemory", "job_context"]
