"""The FastAPI application factory.

``create_app(settings=None)`` builds an app whose settings are read once (from ``REGLIB_*``
environment variables unless given); its lifespan starts the compute pool and waits until every
worker is up (``/readyz`` is ready from then on, except while a worker is being replaced), and on
shutdown refuses new work first, then stops the workers. Nothing heavy happens at import time.

The API docs (``/docs``, Swagger UI, and ``/redoc``) are served offline: ``fastapi-offline`` ships their
scripts and styles, mounted at ``/docs/assets``; the pages name no other host. ReDoc's script would still
fetch its maker's logo from a CDN: ``/redoc`` carries a Content-Security-Policy that keeps every fetch on
this origin (the logo then hides itself).

``app.state`` holds the settings, the pool, the metrics and the :class:`~service.lifecycle.Lifecycle`
whose ``drain()`` ``reglib serve`` awaits on SIGTERM. Middleware, outermost first: metrics, request
context (request id, access log, in-flight count, refusal while draining), request guard (media
types and byte limits).
"""
from __future__ import annotations

import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib import resources

from fastapi import FastAPI
from fastapi.openapi.docs import get_redoc_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline

import reglib

from .config import Settings, SettingsError
from .lifecycle import Lifecycle
from .limits import RequestGuard
from .metrics import Metrics, MetricsMiddleware
from .openapi import state_limits_in_openapi
from .pool import WorkPool
from .problems import install_handlers
from .request_id import RequestContext
from .routes import bundle, confidence, flow, health, match, metrics, page, register, warp
from .routes import filter as filter_routes

__all__ = ["create_app", "DOCS_ASSETS"]

#: Where the API docs' scripts, styles and icon are served (from the ``fastapi-offline`` package).
DOCS_ASSETS = "/docs/assets"
#: ``/redoc``'s policy: everything from this origin (ReDoc injects styles and runs its search in a blob: worker).
REDOC_CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; "
             "worker-src 'self' blob:; object-src 'none'; base-uri 'none'; frame-ancestors 'self'")

DESCRIPTION = """Robust image correspondence and non-rigid registration (the L2E estimator of Ma et al.).

Every answer equals the `reglib` library's answer for the same inputs and `seed` (default 0, recorded
in the answer). Errors are RFC 9457 `application/problem+json`. The web page is at [/](/)."""


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service. ``settings`` defaults to :class:`Settings` read from the environment."""
    if settings is None:
        try:
            settings = Settings()
        except SettingsError as exc:  # `uvicorn --factory service.app:create_app`: one line, no traceback
            print(f"reglib service: error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
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

    app = FastAPIOffline(title="reglib", version=reglib.__version__, description=DESCRIPTION, lifespan=lifespan,
                         static_url=DOCS_ASSETS, redoc_url=None, swagger_ui_parameters={"validatorUrl": None})
    app.state.settings = settings
    app.state.pool = pool
    app.state.metrics = app_metrics
    app.state.lifecycle = lifecycle
    install_handlers(app)
    state_limits_in_openapi(app, settings)
    for module in (filter_routes, register, match, bundle, warp, flow, confidence, health, metrics, page):
        app.include_router(module.router)

    @app.get("/redoc", include_in_schema=False)
    async def redoc() -> HTMLResponse:
        page = get_redoc_html(openapi_url=str(app.openapi_url), title=f"{app.title} - ReDoc",
                              redoc_js_url=f"{DOCS_ASSETS}/redoc.standalone.js",
                              redoc_favicon_url=f"{DOCS_ASSETS}/favicon.png", with_google_fonts=False)
        page.headers["Content-Security-Policy"] = REDOC_CSP
        return page

    static = resources.files("service") / "static"
    app.mount("/static", StaticFiles(directory=str(static)), name="static")

    app.add_middleware(RequestGuard, max_json_bytes=settings.max_json_bytes,
                       max_upload_bytes=settings.max_upload_bytes)
    app.add_middleware(RequestContext, lifecycle=lifecycle, retry_after=settings.retry_after_s,
                       fault_injection=settings.fault_injection)
    app.add_middleware(MetricsMiddleware, metrics=app_metrics)
    return app
