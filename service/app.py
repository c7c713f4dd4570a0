"""The FastAPI application factory.

``create_app(settings=None)`` builds an app whose settings are read once (from ``REGLIB_*``
environment variables unless given); its lifespan starts the compute pool and waits until every
worker is up (``/readyz`` is ready from then on, except while a worker is being replaced), and on
shutdown refuses new work first, then stops the workers. Nothing heavy happens at import time.

``app.state`` holds the settings, the pool, the metrics and the :class:`~service.lifecycle.Lifecycle`
whose ``drain()`` ``reglib serve`` awaits on SIGTERM. Middleware, outermost first: metrics, request
context (request id, access log, in-flight count, refusal while draining), request guard (media
types and byte limits).
"""
from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib import resources

from fastapi import FastAPI
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

import reglib

from .config import Settings
from .lifecycle import Lifecycle
from .limits import RequestGuard
from .metrics import Metrics, MetricsMiddleware
from .openapi import state_limits_in_openapi
from .pool import WorkPool
from .problems import install_handlers
from .request_id import RequestContext
from .routes import confidence, flow, health, match, metrics, register, warp
from .routes import filter as filter_routes

__all__ = ["create_app"]

DESCRIPTION = """Robust image correspondence and non-rigid registration (the L2E estimator of Ma et al.).

Every answer equals the `reglib` library's answer for the same inputs and `seed` (default 0, recorded
in the answer). Errors are RFC 9457 `application/problem+json`. The web page is at [/](/)."""


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service. ``settings`` defaults to :class:`Settings` read from the environment."""
    settings = settings or Settings()
    app_metrics = Metrics()
    pool = WorkPool(workers=settings.workers, queue_size=settings.queue_size, timeout=settings.compute_timeout_s,
                    retry_after=settings.retry_after_s, opencv_max_pixels=settings.opencv_max_pixels,
                    on_change=app_metrics.pool_changed, max_memory=settings.worker_max_memory,
                    on_workers=app_metrics.workers_changed, on_exit=app_metrics.worker_exited)
    lifecycle = Lifecycle(pool, settings.shutdown_grace_s)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await pool.start()
        try:
            yield
        finally:
            await pool.stop()

    app = FastAPI(title="reglib", version=reglib.__version__, description=DESCRIPTION, lifespan=lifespan)
    app.state.settings = settings
    app.state.pool = pool
    app.state.metrics = app_metrics
    app.state.lifecycle = lifecycle
    install_handlers(app)
    state_limits_in_openapi(app, settings)
    for module in (filter_routes, register, match, warp, flow, confidence, health, metrics):
        app.include_router(module.router)

    static = resources.files("service") / "static"
    app.mount("/static", StaticFiles(directory=str(static)), name="static")

    @app.get("/", include_in_schema=False)
    async def page() -> HTMLResponse:
        return HTMLResponse((static / "index.html").read_text(encoding="utf-8"))

    app.add_middleware(RequestGuard, max_json_bytes=settings.max_json_bytes,
                       max_upload_bytes=settings.max_upload_bytes)
    app.add_middleware(RequestContext, lifecycle=lifecycle, retry_after=settings.retry_after_s,
                       fault_injection=settings.fault_injection)
    app.add_middleware(MetricsMiddleware, metrics=app_metrics)
    return app
