"""Cross-origin calls (CORS): off unless ``REGLIB_CORS_ORIGINS`` names the origins whose pages may call the API.

A preflight (``OPTIONS`` with ``Origin`` and ``Access-Control-Request-Method``) from an allowed origin, for
GET, HEAD or POST with only the headers a caller needs (``Authorization``, ``X-API-Key``, ``Content-Type``,
``X-Request-ID``, ``Accept``), is a 204 that names the origin in ``Access-Control-Allow-Origin`` (``*`` when
the setting is ``*``). Any other preflight is a 403 ``CORS_REFUSED`` problem with no
``Access-Control-Allow-*`` header, so the browser sends nothing. The answers to an allowed origin's requests
carry its ``Access-Control-Allow-Origin`` and expose ``X-Request-ID``, ``Retry-After``, ``WWW-Authenticate``
and ``Content-Disposition``; no credentials mode (cookies) is offered: API keys travel in headers.
"""
from __future__ import annotations

from starlette.datastructures import Headers, MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .problems import CORS_REFUSED, MEDIA_TYPE, problem_body

__all__ = ["Cors", "ALLOWED_METHODS", "ALLOWED_HEADERS", "EXPOSED_HEADERS", "MAX_AGE_S"]

ALLOWED_METHODS = ("GET", "HEAD", "POST")
ALLOWED_HEADERS = ("accept", "authorization", "content-type", "x-api-key", "x-request-id")
EXPOSED_HEADERS = ("X-Request-ID", "Retry-After", "WWW-Authenticate", "Content-Disposition")
MAX_AGE_S = 600


class Cors:
    """Answer preflights and mark the answers to allowed origins (``origins``: lower-case, or ``("*",)``)."""

    def __init__(self, app: ASGIApp, *, origins: tuple[str, ...]) -> None:
        self.app = app
        self.any_origin = "*" in origins
        self.origins = frozenset(origins)

    def _allowed(self, origin: str) -> bool:
        return self.any_origin or origin.lower() in self.origins

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = Headers(scope=scope) if scope["type"] == "http" else None
        origin = headers.get("origin") if headers is not None else None
        if headers is None or origin is None:
            await self.app(scope, receive, send)
            return
        if scope.get("method") == "OPTIONS" and "access-control-request-method" in headers:
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
            body = problem_body(403, CORS_REFUSED, refused)
            await send({"type": "http.response.start", "status": 403,
                        "headers": [(b"content-type", MEDIA_TYPE.encode()),
                                    (b"content-length", str(len(body)).encode()), (b"vary", b"Origin")]})
            await send({"type": "http.response.body", "body": body})
            return
        answer = [(b"access-control-allow-origin", ("*" if self.any_origin else origin).encode()),
                  (b"access-control-allow-methods", ", ".join(ALLOWED_METHODS).encode()),
                  (b"access-control-allow-headers", ", ".join(ALLOWED_HEADERS).encode()),
                  (b"access-control-max-age", str(MAX_AGE_S).encode()), (b"vary", b"Origin"),
                  (b"content-length", b"0")]
        await send({"type": "http.response.start", "status": 204, "headers": answer})
        await send({"type": "http.response.body", "body": b""})
