"""API keys: who may call the API, and how many requests one caller may have in flight.

With ``REGLIB_API_KEYS_FILE`` set (:func:`service.config.read_keys`: one key a line, ``#`` comments),
every ``/v1/*`` request, and ``/metrics`` when :func:`metrics_need_key` says so, must name one of the
keys, by ``Authorization: Bearer <key>`` or ``X-API-Key: <key>``. A missing or wrong key is a 401
``UNAUTHORIZED`` problem with ``WWW-Authenticate: Bearer`` (RFC 6750), before a byte of the body is
read. The keys are kept as SHA-256 digests and a presented key is compared, in constant time, with
every one of them. A key is never logged: its *id*, the first 12 hex digits of its digest, names the
caller in the access line and in ``/metrics``. ``/livez``, ``/readyz``, the page, the docs and the
static files stay open. SIGHUP re-reads the file (:meth:`ApiKeys.reload`; a file that cannot be used
then keeps the old keys and logs why).

Each key may have at most ``REGLIB_MAX_IN_FLIGHT_PER_KEY`` requests in flight; one more is a 429
``KEY_BUSY`` problem with ``Retry-After``, so that one caller cannot fill the whole pool.
"""
from __future__ import annotations

import hashlib
import hmac
import ipaddress
import logging
import re
from collections.abc import Iterable

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from .config import Settings, read_keys
from .metrics import Metrics
from .pool import job_context
from .problems import KEY_BUSY, MEDIA_TYPE, UNAUTHORIZED, problem_body

__all__ = ["ApiKeys", "KeyGuard", "key_id", "metrics_need_key", "is_loopback", "CHALLENGE"]

log = logging.getLogger("service.auth")

#: ``WWW-Authenticate`` of a 401 (RFC 6750; ``error="invalid_token"`` added when a key was given but is wrong).
CHALLENGE = 'Bearer realm="reglib"'
_KEY_CHARS = re.compile("[!-~]+")


def _digest(key: str) -> bytes:
    return hashlib.sha256(key.encode("ascii", "surrogateescape")).digest()


def key_id(key: str) -> str:
    """The id that names a caller in logs and metrics: the first 12 hex digits of the key's SHA-256."""
    return _digest(key).hex()[:12]


class ApiKeys:
    """The keys of one keys file, as SHA-256 digests; :meth:`reload` re-reads the file."""

    def __init__(self, path: str, keys: Iterable[str] | None = None) -> None:
        self.path = path
        self._digests: tuple[bytes, ...] = tuple(_digest(k) for k in (read_keys(path) if keys is None else keys))

    def __len__(self) -> int:
        return len(self._digests)

    def identify(self, key: str) -> str | None:
        """The id of ``key`` when it is one of the keys, else None; compared with every key, in constant time."""
        given = _digest(key)
        found = False
        for digest in self._digests:  # no early exit: the time does not tell which key (or whether any) matched
            found |= hmac.compare_digest(given, digest)
        return given.hex()[:12] if found else None

    def reload(self) -> bool:
        """Read the file again; on a file that cannot be used, keep the old keys, log why and answer False."""
        try:
            keys = read_keys(self.path)
        except ValueError as exc:
            log.error("API keys not reloaded: REGLIB_API_KEYS_FILE %s; the %d keys read before stay", exc,
                      len(self._digests))
            return False
        self._digests = tuple(_digest(k) for k in keys)
        log.info("API keys reloaded: %d keys (ids %s)", len(keys), ", ".join(sorted(key_id(k) for k in keys)))
        return True


def is_loopback(host: str | None) -> bool:
    """Whether ``host`` (an address, as in an ASGI scope's ``server``) is a loopback address."""
    try:
        return host is not None and ipaddress.ip_address(host.split("%")[0]).is_loopback
    except ValueError:
        return False


def metrics_need_key(settings: Settings, scope: Scope) -> bool:
    """Whether ``/metrics`` asks this request for a key: ``metrics_access`` open, keys, or auto (keys unless
    the request arrived on a loopback address of this machine)."""
    if settings.metrics_access == "auto":
        server = scope.get("server")
        return not is_loopback(server[0] if server else None)
    return settings.metrics_access == "keys"


def _presented(headers: Headers) -> tuple[str | None, str | None]:
    """``(key, None)`` for the key a request names, ``(None, None)`` for none, ``(None, why)`` when unreadable."""
    bearer = None
    auth = headers.get("authorization")
    if auth is not None:
        scheme, _, token = auth.strip().partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            return None, "`Authorization` must be `Bearer <key>`"
        bearer = token.strip()
    header = (headers.get("x-api-key") or "").strip() or None
    if bearer is not None and header is not None and bearer != header:
        return None, "`Authorization` and `X-API-Key` name two different keys; send one"
    key = bearer or header
    if key is not None and not _KEY_CHARS.fullmatch(key):  # no key of the file is anything else (read_keys)
        return None, "an API key is printable ASCII without spaces"
    return key, None


class KeyGuard:
    """Refuse ``/v1/*`` (and ``/metrics`` when it needs a key) without a valid key (401), and a key's request
    beyond its limit in flight (429); count each key's requests in ``/metrics`` by its id."""

    def __init__(self, app: ASGIApp, *, keys: ApiKeys, settings: Settings, metrics: Metrics) -> None:
        self.app = app
        self.keys = keys
        self.settings = settings
        self.metrics = metrics
        self.in_flight: dict[str, int] = {}

    def _guarded(self, scope: Scope) -> bool:
        path = scope.get("path", "")
        return path.startswith("/v1/") or (path == "/metrics" and metrics_need_key(self.settings, scope))

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not self._guarded(scope):
            await self.app(scope, receive, send)
            return
        key, unreadable = _presented(Headers(scope=scope))
        caller = self.keys.identify(key) if key is not None else None
        if caller is None:
            reason = "missing" if key is None and unreadable is None else "wrong"
            self.metrics.auth_failures.labels(reason).inc()
            if unreadable is not None:
                detail = unreadable
            elif key is None:
                detail = "this service needs an API key: send `Authorization: Bearer <key>` or `X-API-Key: <key>`"
            else:
                detail = "the API key is not one of this service's keys"
            challenge = CHALLENGE if reason == "missing" else CHALLENGE + ', error="invalid_token"'
            await _answer(send, 401, problem_body(401, UNAUTHORIZED, detail), [(b"www-authenticate", challenge)])
            return
        job_context.set({**job_context.get(), "caller": caller})
        limit = self.settings.max_in_flight_per_key
        if self.in_flight.get(caller, 0) >= limit:
            self.metrics.key_rejections.labels(caller).inc()
            detail = (f"this API key has {limit} requests in flight, the most one key may have; send the next one "
                      "when one of them has been answered")
            await _answer(send, 429, problem_body(429, KEY_BUSY, detail),
                          [(b"retry-after", str(self.settings.retry_after_s))])
            return
        self.in_flight[caller] = self.in_flight.get(caller, 0) + 1
        self.metrics.key_requests.labels(caller).inc()
        self.metrics.key_in_flight.labels(caller).inc()
        try:
            await self.app(scope, receive, send)
        finally:
            self.in_flight[caller] -= 1
            if not self.in_flight[caller]:
                del self.in_flight[caller]
            self.metrics.key_in_flight.labels(caller).dec()


async def _answer(send: Send, status: int, body: bytes, headers: list[tuple[bytes, str]]) -> None:
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", MEDIA_TYPE.encode()), (b"content-length", str(len(body)).encode()),
                            *((name, value.encode()) for name, value in headers)]})
    await send({"type": "http.response.body", "body": body})
