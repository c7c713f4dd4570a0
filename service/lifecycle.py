"""The drain: what the service does between SIGTERM and its exit.

:class:`Lifecycle` counts the requests in flight (the request middleware, :mod:`service.request_id`,
enters and leaves it) and knows whether the app is draining. :meth:`Lifecycle.drain` (called by
``reglib serve`` on the first SIGTERM or SIGINT) turns new requests away with 503 and ``/readyz``
to 503 at once, waits up to ``REGLIB_SHUTDOWN_GRACE_S`` for the requests in flight to finish, and
if some are still running then, stops the pool so that they are answered 503 rather than cut off.
The server then closes its listening socket, runs the lifespan's shutdown (the workers are
stopped) and the process exits 0.
"""
from __future__ import annotations

import asyncio
import logging

from .pool import WorkPool

__all__ = ["Lifecycle"]

log = logging.getLogger("service.lifecycle")

_ANSWER_WAIT_S = 3.0  # after a forced pool stop: time for the handlers to send their 503s


class Lifecycle:
    """Requests in flight, and the draining flag, of one app."""

    def __init__(self, pool: WorkPool, grace_s: float) -> None:
        self.pool = pool
        self.grace_s = grace_s
        self.draining = False
        self.in_flight = 0

    def enter(self) -> None:
        self.in_flight += 1

    def leave(self) -> None:
        self.in_flight -= 1

    async def drain(self) -> bool:
        """Refuse new requests and wait for those in flight; True when every one finished within the grace."""
        if self.draining:
            return True
        self.draining = True
        loop = asyncio.get_running_loop()
        log.info("draining: %d requests in flight, up to %g s; new requests get 503", self.in_flight, self.grace_s)
        deadline = loop.time() + self.grace_s
        while self.in_flight > 0 and loop.time() < deadline:
            await asyncio.sleep(0.02)
        if self.in_flight == 0:
            log.info("drained: every request in flight has been answered")
            return True
        log.warning("the %g s grace ended with %d requests in flight; stopping the pool, they get 503",
                    self.grace_s, self.in_flight)
        await self.pool.stop(wait=0)
        deadline = loop.time() + _ANSWER_WAIT_S
        while self.in_flight > 0 and loop.time() < deadline:
            await asyncio.sleep(0.02)
        return False
