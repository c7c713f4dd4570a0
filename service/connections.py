"""The HTTP connections themselves: read deadlines and a cap on open connections (an h11 protocol for uvicorn).

uvicorn's h11 server waits for a request's headers, and for its body, as long as the client likes, and
accepts connections until the process runs out of files, when it stops accepting any, health checks
included. :class:`GuardedH11Protocol` (``reglib serve`` uses it; under uvicorn itself, ``--http
service.connections:GuardedH11Protocol``) adds, from the settings (:class:`ConnectionLimits`):

- **header deadline**: a request's line and headers must have arrived ``REGLIB_HEADER_TIMEOUT_S`` after the
  connection opened or its previous answer ended; else a 408 ``REQUEST_TIMEOUT`` problem when part of a
  request came, nothing when none did, and the connection is closed.
- **body deadline**: while a request's body is read, a pause of ``REGLIB_BODY_TIMEOUT_S`` closes the
  connection the same way (the app reading it sees the client leave). Pauses the server causes itself (it
  stops reading while the app has not taken what came, or the client awaits ``100 Continue``) do not count.
- **a cap**: at most ``REGLIB_MAX_CONNECTIONS`` connections. At the cap, a new connection closes the one
  that has waited longest for a request (an idle keep-alive, or a client slow to send its headers), so idle
  and slow clients cannot shut out the others. When every connection is in the middle of a request, a new
  one still gets in, up to :data:`HEALTH_RESERVE` more, but only for ``/livez`` and ``/readyz``: anything
  else on it is a 503 ``NOT_READY`` problem, and each is closed after one answer. Beyond that reserve, the
  reserve's longest waiting connection makes way, or else the new connection is closed at once.
"""
from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import h11
from starlette.types import Message, Receive, Scope, Send
from uvicorn.protocols.http.h11_impl import H11Protocol

from .config import Settings
from .headers import API_CSP, FIXED_HEADERS
from .problems import MEDIA_TYPE, NOT_READY, REQUEST_TIMEOUT, problem_body

__all__ = ["GuardedH11Protocol", "ConnectionLimits", "guarded_protocol", "HEALTH_PATHS", "HEALTH_RESERVE"]

#: What a connection let in beyond the cap may ask.
HEALTH_PATHS = frozenset({"/livez", "/readyz"})
#: Connections beyond the cap that may ask for health only.
HEALTH_RESERVE = 8


@dataclass(frozen=True)
class ConnectionLimits:
    """The settings :class:`GuardedH11Protocol` works with."""

    header_timeout_s: float
    body_timeout_s: float
    max_connections: int
    retry_after_s: int = 1

    @classmethod
    def of(cls, settings: Settings) -> ConnectionLimits:
        return cls(settings.header_timeout_s, settings.body_timeout_s, settings.max_connections,
                   settings.retry_after_s)


def _raw_answer(status: int, reason: str, body: bytes) -> bytes:
    """A whole HTTP/1.1 answer that closes the connection (written past h11, whose state no longer matters)."""
    headers = {"Content-Type": MEDIA_TYPE, "Content-Length": str(len(body)), "Connection": "close",
               "Cache-Control": "no-store", "Content-Security-Policy": API_CSP, **FIXED_HEADERS}
    head = f"HTTP/1.1 {status} {reason}\r\n" + "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n"
    return head.encode("latin-1") + body


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with header and body deadlines and a cap on open connections (module docs).

    ``limits`` is set by :func:`guarded_protocol`; left None, the first connection reads the settings from
    the ``REGLIB_*`` environment.
    """

    limits: ClassVar[ConnectionLimits | None] = None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if type(self).limits is None:
            type(self).limits = ConnectionLimits.of(Settings())
        self._timer: asyncio.TimerHandle | None = None
        self._timer_kind = ""
        self._waiting_since: float | None = None  # when it began waiting for a request; None during one
        self._last_read = 0.0
        self._health_only = False

    @property
    def _limits(self) -> ConnectionLimits:
        limits = type(self).limits
        assert limits is not None  # set in __init__
        return limits

    # -- the cap ------------------------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        admitted = self._admit()
        super().connection_made(transport)
        if not admitted:
            transport.close()
            return
        if self._health_only:
            self.app = self._health_gate
        self._await_request()

    def _admit(self) -> bool:
        """Whether this new connection may stay (``_health_only`` set when only for health); at the cap, close
        the connection that has waited longest for a request, among the regular ones first."""
        # (the connections already told to close are on their way out)
        others = [c for c in self.connections if isinstance(c, GuardedH11Protocol) and not c.transport.is_closing()]
        health = [c for c in others if c._health_only]
        if len(others) - len(health) < self._limits.max_connections:
            return True
        for pool, health_only in (([c for c in others if not c._health_only], False), (health, True)):
            waiting = [c for c in pool if c._waiting_since is not None]
            if waiting and (not health_only or len(health) >= HEALTH_RESERVE):
                min(waiting, key=lambda c: c._waiting_since or 0.0)._close()
                self._health_only = health_only
                return True
            if health_only and len(health) < HEALTH_RESERVE:
                self._health_only = True
                return True
        return False

    async def _health_gate(self, scope: Scope, receive: Receive, send: Send) -> None:
        """The app of a connection let in beyond the cap: health answered (then closed), anything else 503."""

        async def closing(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), (b"connection", b"close")]}
            await send(message)

        if scope["type"] == "http" and scope.get("path") in HEALTH_PATHS:
            await self.config.loaded_app(scope, receive, closing)
            return
        body = problem_body(503, NOT_READY, "the service has as many connections open as it may; retry shortly")
        await closing({"type": "http.response.start", "status": 503,
                       "headers": [(b"content-type", MEDIA_TYPE.encode()), (b"content-length", str(len(body)).encode()),
                                   (b"retry-after", str(self._limits.retry_after_s).encode()),
                                   (b"cache-control", b"no-store")]})
        await closing({"type": "http.response.body", "body": body})

    # -- the deadlines ------------------------------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        self._last_read = self.loop.time()
        super().data_received(data)
        self._follow()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._follow()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel()
        self._waiting_since = None
        super().connection_lost(exc)

    def _follow(self) -> None:
        """Arm the deadline of what the connection waits for now: a request's headers, or its body."""
        state = self.conn.their_state
        if state is h11.IDLE and (self.cycle is None or self.cycle.response_complete):
            if self._waiting_since is None:
                self._await_request()
        elif state is h11.SEND_BODY:
            self._waiting_since = None
            if self._timer_kind != "body":
                self._arm("body", self._limits.body_timeout_s)
        else:
            self._waiting_since = None
            self._cancel()

    def _await_request(self) -> None:
        self._waiting_since = time.monotonic()
        self._arm("header", self._limits.header_timeout_s)

    def _arm(self, kind: str, delay: float) -> None:
        self._cancel()
        self._timer_kind = kind
        self._timer = self.loop.call_later(delay, self._expired)

    def _cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer, self._timer_kind = None, ""

    def _expired(self) -> None:
        kind = self._timer_kind
        self._timer, self._timer_kind = None, ""
        if self.transport.is_closing():
            return
        if kind == "body":
            cycle = self.cycle
            paused_by_us = self.flow.read_paused or (cycle is not None and cycle.waiting_for_100_continue)
            quiet = self.loop.time() - self._last_read
            if self.conn.their_state is not h11.SEND_BODY:
                return
            if paused_by_us or quiet < self._limits.body_timeout_s:
                self._arm("body", self._limits.body_timeout_s - (0 if paused_by_us else quiet))
                return
        started = kind == "body" and self.cycle is not None and self.cycle.response_started
        partial = kind == "body" or bool(self.conn.trailing_data[0])
        if partial and not started:
            what = "its headers" if kind == "header" else "the next piece of its body"
            limit = self._limits.header_timeout_s if kind == "header" else self._limits.body_timeout_s
            detail = f"the request stopped arriving: {what} did not come within {limit:g} s"
            self.transport.write(_raw_answer(408, "Request Timeout", problem_body(408, REQUEST_TIMEOUT, detail)))
        self._close()

    def _close(self) -> None:
        """Close now; the app, if it is reading this connection's request, sees the client leave."""
        self._cancel()
        self._waiting_since = None
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.disconnected = True
            self.cycle.message_event.set()
        self.transport.close()


def guarded_protocol(settings: Settings) -> type[GuardedH11Protocol]:
    """A :class:`GuardedH11Protocol` class bound to ``settings`` (for ``uvicorn.Config(http=...)``)."""
    return type("GuardedH11Protocol", (GuardedH11Protocol,), {"limits": ConnectionLimits.of(settings)})

