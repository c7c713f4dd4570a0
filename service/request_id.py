"""Request ids, the access line, the in-flight count and the drain refusal: one ASGI middleware.

Every answer carries ``X-Request-ID``: the request's own when it is sane (1 to 128 characters of
``A-Z a-z 0-9 . _ ~ : / + = -``), else a fresh 32-hex-digit id. The id is in
:data:`service.pool.job_context` for the whole request, so every line the request causes (routes,
handlers, the pool's supervisor) names it (:mod:`service.logs`). When the request ends, one access
line is logged (logger ``service.access``: method, path, status, duration_ms, client, and ``caller``,
the id of the request's API key when the service has keys).

While the app drains (after SIGTERM, :mod:`service.lifecycle`), a new request other than
``/livez``, ``/readyz`` and ``/metrics`` gets 503 not-ready with ``Retry-After`` and
``Connection: close``; the requests already in flight are counted here and finish. An exception that
nothing answered becomes a bare 500 problem, logged with its traceback and request id.

Fault injection (``REGLIB_FAULT_INJECTION=true``, tests and the soak only): a request with the
header ``X-Reglib-Fault: crash`` has its job kill its worker instead of computing (see
:mod:`service.pool`). Off by default; the header is ignored then.
"""
from __future__ import annotations

import logging
import re
import time
import uuid

from starlette.datastructures import Headers
from starlette.requests import ClientDisconnect
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .lifecycle import Lifecycle
from .pool import job_context
from .problems import INTERNAL, MEDIA_TYPE, NOT_READY, problem_body

__all__ = ["RequestContext", "HEADER", "FAULT_HEADER", "new_request_id", "sane_request_id"]

HEADER = "X-Request-ID"
FAULT_HEADER = "X-Reglib-Fault"
UNGUARDED = frozenset({"/livez", "/readyz", "/metrics"})
_SANE = re.compile(r"[A-Za-z0-9._~:/+=-]{1,128}")
_HEADER_KEY = HEADER.lower().encode()

log = logging.getLogger("service")
access = logging.getLogger("service.access")


def new_request_id() -> str:
    return uuid.uuid4().hex


def sane_request_id(value: str | None) -> str | None:
    """``value`` when it may be echoed and logged as an id, else None."""
    return value if value is not None and _SANE.fullmatch(value) else None


class RequestContext:
    """Names each request, logs it, counts it in flight, and refuses new ones while draining."""

    def __init__(self, app: ASGIApp, *, lifecycle: Lifecycle, retry_after: int, fault_injection: bool = False) -> None:
        self.app = app
        self.lifecycle = lifecycle
        self.retry_after = retry_after
        self.fault_injection = fault_injection

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        rid = sane_request_id(headers.get(HEADER)) or new_request_id()
        context = {"request_id": rid}
        if self.fault_injection and headers.get(FAULT_HEADER):
            context["fault"] = headers[FAULT_HEADER].strip().lower()
        token = job_context.set(context)
        method, path = scope.get("method", ""), scope.get("path", "")
        status, started = 500, False
        start = time.perf_counter()

        async def send_with_id(message: Message) -> None:
            nonlocal status, started
            if message["type"] == "http.response.start":
                started, status = True, int(message["status"])
                kept = [(k, v) for k, v in message.get("headers", []) if k.lower() != _HEADER_KEY]
                message = {**message, "headers": [*kept, (_HEADER_KEY, rid.encode())]}
            await send(message)

        try:
            if self.lifecycle.draining and path not in UNGUARDED:
                await _answer(send_with_id, 503, problem_body(503, NOT_READY, "the service is shutting down; retry "
                                                              "on another instance or shortly"),
                              [(b"retry-after", str(self.retry_after).encode()), (b"connection", b"close")])
                return
            self.lifecycle.enter()
            try:
                await self.app(scope, receive, send_with_id)
            finally:
                self.lifecycle.leave()
        except ClientDisconnect:
            status = 499  # the client left before its request was read (nginx's code); nothing to answer
        except Exception:
            log.exception("unhandled error on %s %s", method, path)
            if not started:
                await _answer(send_with_id, 500, problem_body(500, INTERNAL, "an internal error occurred; it has been "
                                                              "logged"), [])
        finally:
            ms = (time.perf_counter() - start) * 1e3
            client = scope.get("client")
            caller = job_context.get().get("caller")  # the API key's id (service.auth), never the key
            access.info("%s %s %d %.1f ms%s", method, path, status, ms, f" key {caller}" if caller else "",
                        extra={"method": method, "path": path, "status": status, "duration_ms": round(ms, 1),
                               "client": client[0] if client else None, **({"caller": caller} if caller else {})})
            job_context.reset(token)


async def _answer(send: Send, status: int, body: bytes, headers: list[tuple[bytes, bytes]]) -> None:
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", MEDIA_TYPE.encode()), (b"content-length", str(len(body)).encode()),
                            *headers]})
    await send({"type": "http.response.body", "body": body})
