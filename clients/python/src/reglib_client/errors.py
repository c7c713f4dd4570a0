"""Errors raised by the client, parsed from the service's RFC 9457 problem+json bodies.

::

    ApiError                  status, type, title, detail (and retry_after where the server sent one)
    +-- InvalidInput          400, 415, 422: the request is wrong; fix it, do not retry
    +-- Unauthorized          401: the service needs an API key and got none, or a wrong one
    +-- TooLarge              413: an upload over the byte or pixel limit
    +-- Overloaded            429, 503: still busy after the retries (retry_after: seconds, or None)
    +-- Timeout               504 (the server's compute limit) or a client-side timeout (status None)
    +-- Unreachable           the connection failed on every attempt (status None)
    +-- MalformedResponse     a response the client cannot read (not JSON, missing fields, ...)

Every error carries the HTTP ``status`` (``None`` when no response came), the problem ``type``
URI (``"about:blank"`` when the body was not problem+json), ``title`` and ``detail``.
"""
from __future__ import annotations

from typing import Any

__all__ = ["ApiError", "InvalidInput", "Unauthorized", "TooLarge", "Overloaded", "Timeout", "Unreachable",
           "MalformedResponse", "error_for"]


class ApiError(Exception):
    """A request to the service failed; base class of every error the client raises on purpose.

    Attributes
    ----------
    status : int or None
        HTTP status of the response, ``None`` when none came (client timeout, connection failure).
    type : str
        The problem ``type`` URI, e.g. ``".../too-large"``; ``"about:blank"`` when not given.
    title : str
        Short human-readable summary of the problem type.
    detail : str
        What went wrong with this request.
    retry_after : float or None
        Seconds the server asked to wait (``Retry-After``), when it sent one.
    body : dict
        The whole problem document (extension members included), empty when there was none.
    """

    def __init__(self, status: int | None, type: str = "about:blank", detail: str = "", title: str = "", *,
                 retry_after: float | None = None, body: dict[str, Any] | None = None) -> None:
        self.status = status
        self.type = type
        self.title = title
        self.detail = detail
        self.retry_after = retry_after
        self.body = dict(body or {})
        where = f"HTTP {status}" if status is not None else "no response"
        text = ": ".join(part for part in (title, detail) if part)
        super().__init__(f"{where}: {text}" if text else where)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(status={self.status!r}, type={self.type!r}, "
                f"title={self.title!r}, detail={self.detail!r})")


class InvalidInput(ApiError):
    """400, 415 or 422: the body, an image, a shape or an option was rejected; retrying will not help."""


class Unauthorized(ApiError):
    """401: the service needs an API key (``Client(..., api_key=...)`` or ``REGLIB_API_KEY``) and got none,
    or a wrong one; retrying will not help."""


class TooLarge(ApiError):
    """413: an upload is over the service's byte limit or an image over its pixel limit."""


class Overloaded(ApiError):
    """429 (queue full) or 503 (not ready), still so after the client's retries."""


class Timeout(ApiError):
    """504 (the request ran past the server's compute limit) or a client-side timeout (status None)."""


class Unreachable(ApiError):
    """No connection could be made (or it broke) on every attempt; ``status`` is None."""


class MalformedResponse(ApiError):
    """The service answered, but not in a form the client understands."""


_BY_STATUS: dict[int, type[ApiError]] = {400: InvalidInput, 401: Unauthorized, 415: InvalidInput, 422: InvalidInput,
                                         413: TooLarge,
                                         429: Overloaded, 503: Overloaded, 504: Timeout}


def error_for(status: int) -> type[ApiError]:
    """The error class for an HTTP error ``status`` (``ApiError`` itself for the others, e.g. 500)."""
    return _BY_STATUS.get(status, ApiError)
