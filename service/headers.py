"""Security headers on every answer: a Content-Security-Policy, no framing, no sniffing, no referrer.

- HTML (the page ``/``): :data:`PAGE_CSP`, the page's own scripts and styles only (``/static``; no inline
  script anywhere), images from this origin, ``data:`` and the ``blob:`` URLs the page makes of its answers.
- Everything else (the API's JSON, files, problems): :data:`API_CSP`, ``default-src 'none'``.
- A route that sets its own policy keeps it: the API docs (:mod:`service.routes.docs`), whose start-up
  scripts are allowed by their SHA-256 (:func:`inline_script_policy`), not by ``'unsafe-inline'``.

With either policy: ``X-Content-Type-Options: nosniff``, ``X-Frame-Options: DENY`` (``frame-ancestors
'none'`` in the policy says the same to current browsers) and ``Referrer-Policy: no-referrer``.

Answers under ``/v1/`` (results and problems alike) carry ``Cache-Control: no-store``: they are one caller's
data, computed for that request. A ``Location`` is made relative (path and query only): Starlette's
trailing-slash redirect (``/docs/`` -> ``/docs``) writes the request's own ``Host`` header into it, which
the caller chooses, so an absolute one could send a browser to any host.
"""
from __future__ import annotations

import base64
import hashlib
import re
from urllib.parse import urlsplit

from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["SecurityHeaders", "PAGE_CSP", "API_CSP", "FIXED_HEADERS", "inline_script_policy", "relative_location"]

PAGE_CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
            "connect-src 'self' blob:; object-src 'none'; base-uri 'none'; form-action 'self'; "
            "frame-ancestors 'none'")
API_CSP = "default-src 'none'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
FIXED_HEADERS = {"X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY", "Referrer-Policy": "no-referrer"}

_LEADING_SLASHES = re.compile(r"^[/\\]*")
_INLINE_SCRIPT = re.compile(r"<script>(.*?)</script>", re.S)


def inline_script_policy(html: str, policy: str) -> str:
    """``policy`` with ``script-src 'self'`` extended by the ``'sha256-...'`` of each inline script of ``html``."""
    hashes = " ".join(f"'sha256-{base64.b64encode(hashlib.sha256(s.encode()).digest()).decode()}'"
                      for s in _INLINE_SCRIPT.findall(html))
    return policy.replace("script-src 'self'", f"script-src 'self' {hashes}".rstrip(), 1)


def relative_location(location: str) -> str:
    """The path and query of ``location``, starting with exactly one ``/`` (a browser reads ``//host`` or
    ``/\\host`` as another host)."""
    parts = urlsplit(location)
    path = _LEADING_SLASHES.sub("/", parts.path) if parts.path else "/"
    return path + (f"?{parts.query}" if parts.query else "")


class SecurityHeaders:
    """Add the policy and the fixed headers to every HTTP answer that does not set them itself, ``no-store`` to
    the API's answers, and make a ``Location`` relative."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        api = scope.get("path", "").startswith("/v1/")

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message.setdefault("headers", [])
                headers = MutableHeaders(scope=message)
                if "content-security-policy" not in headers:
                    html = headers.get("content-type", "").startswith("text/html")
                    headers["Content-Security-Policy"] = PAGE_CSP if html else API_CSP
                for name, value in FIXED_HEADERS.items():
                    headers.setdefault(name, value)
                if api:
                    headers["Cache-Control"] = "no-store"
                if "location" in headers:
                    headers["Location"] = relative_location(headers["location"])
            await send(message)

        await self.app(scope, receive, with_headers)
