"""RFC 9457 problem details: the ``type`` URIs (one constant per kind), the table that answers each
exception class (:data:`PROBLEMS`) and the exception handlers.

Every error the service answers is ``application/problem+json`` with ``type``, ``title``,
``status`` and ``detail``. Details come from our own messages (which name the argument, never a
server path); an unexpected exception is logged with its traceback and answered as a bare 500.
A request whose job killed its worker process twice is a 500 of its own type (``WORKER_CRASHED``);
one that needed more memory than a worker may use is a 413 ``TOO_LARGE``. The guards in front of the
routes answer with their own types: ``UNAUTHORIZED`` (401, with ``WWW-Authenticate``) and ``KEY_BUSY``
(429, with ``Retry-After``) from :mod:`service.auth`, ``CORS_REFUSED`` (403) from :mod:`service.cors`; the
connections themselves (:mod:`service.connections`) answer ``REQUEST_TIMEOUT`` (408) and ``NOT_READY`` (503).
"""
from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException
from starlette.responses import Response

from reglib.errors import EstimationError, ImageTooLarge, InputError, UnsupportedFormat

from .pool import ComputeTimeout, NotReady, Overloaded, UndecodableImage, WorkerCrashed, WorkerOutOfMemory

__all__ = ["BASE", "INVALID_BODY", "UNDECODABLE_IMAGE", "TOO_LARGE", "UNSUPPORTED_FORMAT", "INVALID_INPUT",
           "ESTIMATION_FAILED", "OVERLOADED", "NOT_READY", "TIMEOUT", "INTERNAL", "NOT_FOUND",
           "METHOD_NOT_ALLOWED", "WORKER_CRASHED", "UNAUTHORIZED", "KEY_BUSY", "CORS_REFUSED", "REQUEST_TIMEOUT",
           "Problem", "ProblemKind", "PROBLEMS", "problem_kind", "problem_body",
           "problem_response", "from_library_error", "install_handlers", "MEDIA_TYPE"]

log = logging.getLogger("service")

MEDIA_TYPE = "application/problem+json"
BASE = "https://reglib.dev/problems/"
INVALID_BODY = BASE + "invalid-body"                # 400
UNDECODABLE_IMAGE = BASE + "undecodable-image"      # 400
TOO_LARGE = BASE + "too-large"                      # 413
UNSUPPORTED_FORMAT = BASE + "unsupported-format"    # 415
INVALID_INPUT = BASE + "invalid-input"              # 422
ESTIMATION_FAILED = BASE + "estimation-failed"      # 422
OVERLOADED = BASE + "overloaded"                    # 429
NOT_READY = BASE + "not-ready"                      # 503
TIMEOUT = BASE + "timeout"                          # 504
INTERNAL = BASE + "internal"                        # 500
WORKER_CRASHED = BASE + "worker-crashed"            # 500 (the request crashed a worker, twice)
NOT_FOUND = BASE + "not-found"                      # 404 (routing)
METHOD_NOT_ALLOWED = BASE + "method-not-allowed"    # 405 (routing)
UNAUTHORIZED = BASE + "unauthorized"                # 401 (no API key, or not one of the service's)
KEY_BUSY = BASE + "key-busy"                        # 429 (this API key has its limit of requests in flight)
CORS_REFUSED = BASE + "cors-refused"                # 403 (a preflight, or without API keys a page's request,
                                                    # from an origin that is not allowed)
REQUEST_TIMEOUT = BASE + "request-timeout"          # 408 (a request's headers or body stopped arriving)

_TITLES = {
    INVALID_BODY: "The request body cannot be parsed",
    UNDECODABLE_IMAGE: "An image cannot be decoded",
    TOO_LARGE: "The request is over a size limit",
    UNSUPPORTED_FORMAT: "The format is not allowed",
    INVALID_INPUT: "The input is invalid",
    ESTIMATION_FAILED: "The estimation failed on this input",
    OVERLOADED: "The work queue is full",
    NOT_READY: "The service is not ready",
    TIMEOUT: "The computation ran past its time limit",
    INTERNAL: "Internal server error",
    WORKER_CRASHED: "The request crashed a worker",
    NOT_FOUND: "Not found",
    METHOD_NOT_ALLOWED: "Method not allowed",
    UNAUTHORIZED: "An API key is needed",
    KEY_BUSY: "Too many requests in flight for this API key",
    CORS_REFUSED: "Cross-origin request refused",
    REQUEST_TIMEOUT: "The request did not arrive in time",
}


class Problem(HTTPException):
    """An error answered as a problem document (raise it anywhere in a request)."""

    def __init__(self, status: int, type_: str, detail: str, *, headers: dict[str, str] | None = None,
                 extra: dict[str, Any] | None = None) -> None:
        super().__init__(status_code=status, detail=detail, headers=headers)
        self.type = type_
        self.extra = extra or {}


def problem_body(status: int, type_: str, detail: str, extra: dict[str, Any] | None = None) -> bytes:
    body = {"type": type_, "title": _TITLES.get(type_, "Error"), "status": status, "detail": detail}
    body.update(extra or {})
    return json.dumps(body, allow_nan=False, default=str).encode()


def problem_response(status: int, type_: str, detail: str, *, headers: Mapping[str, str] | None = None,
                     extra: dict[str, Any] | None = None) -> Response:
    return Response(problem_body(status, type_, detail, extra), status_code=status, headers=headers,
                    media_type=MEDIA_TYPE)


@dataclass(frozen=True, slots=True)
class ProblemKind:
    """How one exception class is answered: its ``status`` and problem ``type`` (the title is the type's)."""

    status: int
    type: str

    @property
    def title(self) -> str:
        return _TITLES[self.type]


#: The answer to each exception class a library call, a job or the pool raises on purpose. An exception
#: is answered by the first of its classes (its MRO) listed here, so a subclass may be listed to be
#: answered differently from its base (``ImageTooLarge`` is an ``InputError``, but a 413).
PROBLEMS: Mapping[type[Exception], ProblemKind] = MappingProxyType({
    InputError: ProblemKind(422, INVALID_INPUT),
    ImageTooLarge: ProblemKind(413, TOO_LARGE),
    UnsupportedFormat: ProblemKind(415, UNSUPPORTED_FORMAT),
    UndecodableImage: ProblemKind(400, UNDECODABLE_IMAGE),
    EstimationError: ProblemKind(422, ESTIMATION_FAILED),
    Overloaded: ProblemKind(429, OVERLOADED),
    NotReady: ProblemKind(503, NOT_READY),
    ComputeTimeout: ProblemKind(504, TIMEOUT),
    WorkerCrashed: ProblemKind(500, WORKER_CRASHED),
    WorkerOutOfMemory: ProblemKind(413, TOO_LARGE),
})


def problem_kind(exc: BaseException) -> ProblemKind | None:
    """The :data:`PROBLEMS` entry of the first class in ``type(exc).__mro__`` listed there; None for none."""
    for cls in type(exc).__mro__:
        kind = PROBLEMS.get(cls)
        if kind is not None:
            return kind
    return None


def from_library_error(exc: BaseException) -> Problem | None:
    """The problem for an exception of :data:`PROBLEMS` (raised in a worker or here), or None for anything else."""
    kind = problem_kind(exc)
    if kind is None:
        return None
    # Overloaded and NotReady (its subclass) say when to come back
    headers = {"Retry-After": str(exc.retry_after)} if isinstance(exc, Overloaded) else None
    return Problem(kind.status, kind.type, str(exc), headers=headers)


def _validation_detail(errors: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], str]:
    clean = []
    for err in errors[:20]:
        loc = [str(p) for p in err.get("loc", ())]
        clean.append({"loc": loc, "msg": str(err.get("msg", ""))[:300], "type": str(err.get("type", ""))})
    summary = "; ".join(f"{'.'.join(e['loc'])}: {e['msg']}" for e in clean[:5])
    return clean, summary


async def _problem_handler(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, Problem)
    return problem_response(exc.status_code, exc.type, str(exc.detail), headers=exc.headers, extra=exc.extra)


async def _http_handler(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    status = exc.status_code
    type_ = {404: NOT_FOUND, 405: METHOD_NOT_ALLOWED, 413: TOO_LARGE, 415: UNSUPPORTED_FORMAT,
             422: INVALID_INPUT}.get(status, INVALID_BODY if 400 <= status < 500 else INTERNAL)
    detail = exc.detail if isinstance(exc.detail, str) else _TITLES.get(type_, "Error")
    return problem_response(status, type_, detail, headers=exc.headers)


async def _validation_handler(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, RequestValidationError)
    errors, summary = _validation_detail(list(exc.errors()))
    if any(e["type"] == "json_invalid" for e in errors):
        return problem_response(400, INVALID_BODY, f"the body is not valid JSON: {summary}", extra={"errors": errors})
    return problem_response(422, INVALID_INPUT, summary or "invalid request", extra={"errors": errors})


async def _library_handler(request: Request, exc: Exception) -> Response:
    problem = from_library_error(exc)
    if problem is None:
        return await _internal_handler(request, exc)
    return await _problem_handler(request, problem)


async def _internal_handler(request: Request, exc: Exception) -> Response:
    log.error("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
    return problem_response(500, INTERNAL, "an internal error occurred; it has been logged")


def install_handlers(app: FastAPI) -> None:
    """Register the handlers that turn every error into a problem document."""
    app.add_exception_handler(Problem, _problem_handler)
    app.add_exception_handler(HTTPException, _http_handler)
    app.add_exception_handler(RequestValidationError, _validation_handler)
    for cls in PROBLEMS:
        app.add_exception_handler(cls, _library_handler)
    app.add_exception_handler(Exception, _internal_handler)
