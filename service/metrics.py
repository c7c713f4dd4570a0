"""Prometheus metrics of one app (its own registry, so several apps in one process never clash).

- ``reglib_http_requests_total{method, route, status}``  requests answered, by method (GET, HEAD, POST, OPTIONS,
  or ``other``) and route template: the API's
  routes, ``/docs``, ``/redoc``, ``/openapi.json`` and each mount of static files (``/static``, ``/docs/assets``)
  by its own path; ``unmatched`` for a path no route serves
- ``reglib_http_request_duration_seconds{method, route}``  latency histogram
- ``reglib_http_in_flight``  requests being handled now
- ``reglib_work_running`` / ``reglib_work_queued``  pool jobs computing / waiting for a worker
- ``reglib_rejections_total{reason}``  requests refused: overloaded, not_ready, timeout, too_large, ...
- ``reglib_workers_alive``  worker processes alive (fewer than configured while one is being replaced)
- ``reglib_worker_exits_total{reason}``  workers replaced: crashed, timeout (killed at the time limit),
  memory (a job hit the worker memory cap)
- with API keys (:mod:`service.auth`), by key id (12 hex digits of the key's SHA-256, never the key):
  ``reglib_key_requests_total{key}`` requests let in, ``reglib_key_in_flight{key}`` being handled now,
  ``reglib_key_rejections_total{key}`` refused (429) at the key's limit in flight; and
  ``reglib_auth_failures_total{reason}`` requests refused with 401: missing (no key) or wrong
"""
from __future__ import annotations

import time

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    generate_latest,
)
from prometheus_client.exposition import CONTENT_TYPE_LATEST
from starlette.routing import BaseRoute, Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["Metrics", "MetricsMiddleware", "CONTENT_TYPE_LATEST", "route_label", "method_label", "METHODS"]

#: The ``method`` label's values: the methods the service answers, and ``other`` for any other token (HTTP lets a
#: client make up methods, and each distinct label value is a new series kept for the life of the process).
METHODS = ("GET", "HEAD", "POST", "OPTIONS")

_REASONS = {401: "unauthorized", 413: "too_large", 415: "unsupported_format", 429: "overloaded", 503: "not_ready",
            504: "timeout"}


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        self.requests = Counter("reglib_http_requests", "HTTP requests answered", ["method", "route", "status"],
                                registry=self.registry)
        self.latency = Histogram("reglib_http_request_duration_seconds", "Time to answer a request",
                                 ["method", "route"], registry=self.registry,
                                 buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60))
        self.in_flight = Gauge("reglib_http_in_flight", "Requests being handled", registry=self.registry)
        self.running = Gauge("reglib_work_running", "Pool jobs computing", registry=self.registry)
        self.queued = Gauge("reglib_work_queued", "Pool jobs waiting for a worker", registry=self.registry)
        self.rejections = Counter("reglib_rejections", "Requests refused, by reason", ["reason"],
                                  registry=self.registry)
        self.workers_alive = Gauge("reglib_workers_alive", "Worker processes alive", registry=self.registry)
        self.worker_exits = Counter("reglib_worker_exits", "Workers replaced, by reason", ["reason"],
                                    registry=self.registry)
        self.key_requests = Counter("reglib_key_requests", "Requests let in, by API key id", ["key"],
                                    registry=self.registry)
        self.key_in_flight = Gauge("reglib_key_in_flight", "Requests being handled, by API key id", ["key"],
                                   registry=self.registry)
        self.key_rejections = Counter("reglib_key_rejections", "Requests refused at the key's limit in flight, "
                                      "by API key id", ["key"], registry=self.registry)
        self.auth_failures = Counter("reglib_auth_failures", "Requests refused for want of a valid API key",
                                     ["reason"], registry=self.registry)

    def pool_changed(self, running: int, queued: int) -> None:
        self.running.set(running)
        self.queued.set(queued)

    def workers_changed(self, alive: int) -> None:
        self.workers_alive.set(alive)

    def worker_exited(self, reason: str) -> None:
        self.worker_exits.labels(reason).inc()

    def render(self) -> bytes:
        return generate_latest(self.registry)


class MetricsMiddleware:
    """Counts every HTTP request by its route template (not the raw path: bounded label values)."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        status = 500
        start = time.perf_counter()

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        # what the router matches against, kept before routing rewrites the scope (a mount sets root_path)
        probe = {"type": "http", "path": scope.get("path", ""), "root_path": scope.get("root_path", ""),
                 "method": scope.get("method", "")}
        self.metrics.in_flight.inc()
        try:
            await self.app(scope, receive, send_status)
        finally:
            self.metrics.in_flight.dec()
            path = getattr(scope.get("route"), "path", None) or route_label(scope.get("app"), probe)
            method = method_label(scope.get("method", ""))
            self.metrics.requests.labels(method, path, str(status)).inc()
            self.metrics.latency.labels(method, path).observe(time.perf_counter() - start)
            if status in _REASONS:
                self.metrics.rejections.labels(_REASONS[status]).inc()


def method_label(method: str) -> str:
    """``method`` when it is one of :data:`METHODS`, else ``"other"``."""
    return method if method in METHODS else "other"


def route_label(app: object, scope: Scope) -> str:
    """The path template of the route of ``app`` that serves ``scope``, for the requests that do not name
    their route in the scope as the API's do: Starlette's plain routes such as ``/docs`` and ``/openapi.json``,
    mounts (labelled by their mount path), and requests refused before routing (401, 413, 415, 429, 503 from
    the middleware); a route that matches all but the method counts too (405). ``"unmatched"`` when none does."""
    return _label(list(getattr(app, "routes", None) or []), scope) or "unmatched"


def _label(routes: list[BaseRoute], scope: Scope) -> str | None:
    partial = None
    for route in routes:
        match, _child = route.matches(scope)
        if match is Match.NONE:
            continue
        path = getattr(route, "path", None)
        if not path:  # an included router (FastAPI wraps each one): the route inside it that matches
            inner = getattr(route, "original_router", None)
            path = _label(list(getattr(inner, "routes", None) or []), scope)
        if match is Match.FULL and path:
            return str(path)
        if match is Match.PARTIAL and path and partial is None:
            partial = str(path)
    return partial
