"""Cross-origin calls (CORS): off unless ``REGLIB_CORS_ORIGINS`` names the origins whose pages may call the API.

A preflight (``OPTIONS`` with ``Origin`` and ``Access-Control-Request-Method``) from an allowed origin, for
GET, HEAD or POST with only the headers a caller needs (``Authorization``, ``X-API-Key``, ``Content-Type``,
``X-Request-ID``, ``Accept``), is a 204 that names the origin in ``Access-Control-Allow-Origin`` (``*`` when
the setting is ``*``). Any other preflight is a 403 ``CORS_REFUSED`` problem with no
``Access-Control-Allow-*`` header, so the browser sends nothing. The answers to an allowed origin's requests
carry its ``Access-Control-Allow-Origin`` and expose ``X-Request-ID``, ``Retry-After``, ``WWW-Authenticate``
and ``Content-Disposition``; no credentials mode (cookies) is offered: API keys travel in headers.

Without API keys, a ``/v1/*`` request that a browser sends for a page of another origin is refused (403
``CORS_REFUSED``, before its body is read) unless that origin is allowed: a plain multipart POST needs no
preflight, so without this any page a user visits could make the service compute (and read nothing back,
but spend its workers). A request is cross-origin when ``Sec-Fetch-Site`` says ``cross-site`` or
``same-site``, or, from a browser that does not send it, when ``Origin`` names another origin than the
request's own (scheme and ``Host``). With keys, the key decides, as for any other caller.
"""
from __future__ import annotations

from urllib.parse import urlsplit

from starlette.datastructures import Headers, MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .problems import CORS_REFUSED, MEDIA_TYPE, problem_body

__all__ = ["Cors", "cross_origin", "ALLOWED_METHODS", "ALLOWED_HEADERS", "EXPOSED_HEADERS", "MAX_AGE_S"]

ALLOWED_METHODS = ("GET", "HEAD", "POST")
ALLOWED_HEADERS = ("accept", "authorization", "content-type", "x-api-key", "x-request-id")
EXPOSED_HEADERS = ("X-Request-ID", "Retry-After", "WWW-Authenticate", "Content-Disposition")
MAX_AGE_S = 600


class Cors:
    """Answer preflights and mark the answers to allowed origins (``origins``: lower-case, or ``("*",)``)."""

    def __init__(self, app: ASGIApp, *, origins: tuple[str, ...], keys: bool = False) -> None:
        self.app = app
        self.any_origin = "*" in origins
        self.origins = frozenset(origins)
        self.keys = keys

    def _allowed(self, origin: str) -> bool:
        return self.any_origin or origin.lower() in self.origins

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = Headers(scope=scope) if scope["type"] == "http" else None
        if headers is None:
            await self.app(scope, receive, send)
            return
        origin = headers.get("origin")
        preflight = scope.get("method") == "OPTIONS" and "access-control-request-method" in headers
        if (not self.keys and not preflight and scope.get("path", "").startswith("/v1/")
                and cross_origin(scope, headers) and not (origin is not None and self._allowed(origin))):
            shown = repr(origin) if origin is not None else "another site"
            await _refuse(send, f"a page of {shown} may not call this service; the service's REGLIB_CORS_ORIGINS "
                                "names the origins whose pages may (or give the service API keys)")
            return
        if origin is None:
            await self.app(scope, receive, send)
            return
        if preflight:
            await self._preflight(origin, headers, send)
            return
        allowed = self._allowed(origin)

        async def marked(message: Message) -> None:
            if message["type"] == "http.response.start":
                message.setdefault("headers", [])
                out = MutableHeaders(scope=message)
                if allowed:
                    out["Access-Control-Allow-Origin"] = "*" if self.any_origin else origin
                    out["Access-Control-Expose-Headers"] = ", ".join(EXPOSED_HEADERS)
                if not self.any_origin:
                    out.add_vary_header("Origin")
            await send(message)

        await self.app(scope, receive, marked)

    async def _preflight(self, origin: str, headers: Headers, send: Send) -> None:
        method = headers["access-control-request-method"].strip().upper()
        asked = [h.strip().lower() for h in headers.get("access-control-request-headers", "").split(",") if h.strip()]
        refused = None
        if not self._allowed(origin):
            refused = (f"origin {origin!r} may not call this service; the service's REGLIB_CORS_ORIGINS names the "
                       "origins that may")
        elif method not in ALLOWED_METHODS:
            refused = f"method {method!r} is not allowed cross-origin; allowed: {list(ALLOWED_METHODS)}"
        elif set(asked) - set(ALLOWED_HEADERS):
            refused = (f"header(s) {sorted(set(asked) - set(ALLOWED_HEADERS))} are not allowed cross-origin; "
                       f"allowed: {list(ALLOWED_HEADERS)}")
        if refused is not None:
            await _refuse(send, refused)
            return
        answer = [(b"access-control-allow-origin", ("*" if self.any_origin else origin).encode()),
                  (b"access-control-allow-methods", ", ".join(ALLOWED_METHODS).encode()),
                  (b"access-control-allow-headers", ", ".join(ALLOWED_HEADERS).encode()),
                  (b"access-control-max-age", str(MAX_AGE_S).encode()), (b"vary", b"Origin"),
                  (b"content-length", b"0")]
        await send({"type": "http.response.start", "status": 204, "headers": answer})
        await send({"type": "http.response.body", "body": b""})


def _default_port(scheme: str) -> str:
    return "443" if scheme in ("https", "wss") else "80"


def cross_origin(scope: Scope, headers: Headers) -> bool:
    """Whether a browser sent this request for a page of another origin (``Sec-Fetch-Site``; else ``Origin``
    against the request's own scheme and ``Host``)."""
    site = headers.get("sec-fetch-site", "").strip().lower()
    if site in ("cross-site", "same-site"):
        return True
    if site in ("same-origin", "none"):
        return False
    origin = headers.get("origin")
    if origin is None:
        return False
    parts = urlsplit(origin.strip().lower())
    if not parts.scheme or not parts.hostname:  # `null` (a sandboxed or file: page) or garbage
        return True
    host = urlsplit("//" + headers.get("host", "").strip().lower())
    scheme = str(scope.get("scheme", "http"))
    try:
        ours = (scheme, host.hostname, str(host.port or _default_port(scheme)))
        theirs = (parts.scheme, parts.hostname, str(parts.port or _default_port(parts.scheme)))
    except ValueError:  # a port that is not a number
        return True
    return ours != theirs


async def _refuse(send: Send, detail: str) -> None:
    body = problem_body(403, CORS_REFUSED, detail)
    await send({"type": "http.response.start", "status": 403,
                "headers": [(b"content-type", MEDIA_TYPE.encode()), (b"content-length", str(len(body)).encode()),
                            (b"vary", b"Origin")]})
    await send({"type": "http.response.body", "body": body})
