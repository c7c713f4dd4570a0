"""The FastAPI application factory.

``create_app(settings=None)`` builds an app whose settings are read once (from ``REGLIB_*``
environment variables unless given); its lifespan starts the compute pool and waits until every
worker is up (``/readyz`` is ready from then on, except while a worker is being replaced), and on
shutdown refuses new work first, then stops the workers. Nothing heavy happens at import time.

The API docs (``/docs``, Swagger UI, and ``/redoc``) are served offline (:mod:`service.routes.docs`).

With ``REGLIB_API_KEYS_FILE`` set, ``/v1/*`` needs a key (:mod:`service.auth`; SIGHUP re-reads the file);
without keys, a bind beyond loopback logs one warning once the server listens (:mod:`service.exposure`).

``app.state`` holds the settings, the pool, the metrics and the :class:`~service.lifecycle.Lifecycle`
whose ``drain()`` ``reglib serve`` awaits on SIGTERM. Middleware, outermost first: metrics, security
headers (:mod:`service.headers`), request context (request id, access log, in-flight count, refusal while
draining), CORS (:mod:`service.cors`), API keys (only with keys), request guard (media types and byte
limits).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import sys
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib import resources

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline

import reglib

from .auth import ApiKeys, KeyGuard
from .config import Settings, SettingsError
from .cors import Cors
from .exposure import watch_exposure
from .headers import SecurityHeaders
from .lifecycle import Lifecycle
from .limits import RequestGuard
from .metrics import Metrics, MetricsMiddleware
from .openapi import state_limits_in_openapi
from .pool import WorkPool
from .problems import install_handlers
from .request_id import RequestContext
from .routes import bundle, confidence, docs, flow, health, match, metrics, page, register, warp
from .routes import filter as filter_routes
from .routes.docs import DOCS_ASSETS

__all__ = ["create_app", "DOCS_ASSETS"]

log = logging.getLogger("service")

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
    keys = ApiKeys(settings.api_keys_file) if settings.api_keys_file is not None else None

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await pool.start()
        if keys is not None:  # said at start-up, so whoever started it knows that /v1/* needs a key
            log.info("API keys on (%d keys, from REGLIB_API_KEYS_FILE): /v1/* needs one", len(keys))
        else:
            log.info("API keys off: /v1/* is open to whoever reaches it (REGLIB_API_KEYS_FILE sets keys)")
        watch = asyncio.create_task(watch_exposure(keys is not None))
        # SIGHUP re-reads the keys where signals can be had: the server's main thread (not a TestClient's)
        reloads = keys is not None and threading.current_thread() is threading.main_thread()
        if keys is not None and reloads:
            asyncio.get_running_loop().add_signal_handler(signal.SIGHUP, keys.reload)
        try:
            yield
        finally:
            if reloads:
                asyncio.get_running_loop().remove_signal_handler(signal.SIGHUP)
            watch.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watch
            await pool.stop()

    app = FastAPIOffline(title="reglib", version=reglib.__version__, description=DESCRIPTION, lifespan=lifespan,
                         static_url=DOCS_ASSETS, docs_url=None, redoc_url=None,
                         swagger_ui_parameters={"validatorUrl": None})
    app.state.settings = settings
    app.state.pool = pool
    app.state.metrics = app_metrics
    app.state.lifecycle = lifecycle
    app.state.api_keys = keys
    install_handlers(app)
    state_limits_in_openapi(app, settings)
    for module in (filter_routes, register, match, bundle, warp, flow, confidence, health, metrics, page, docs):
        app.include_router(module.router)

    static = resources.files("service") / "static"
    app.mount("/static", StaticFiles(directory=str(static)), name="static")

    # added innermost first
    app.add_middleware(RequestGuard, max_json_bytes=settings.max_json_bytes,
                       max_upload_bytes=settings.max_upload_bytes, max_points=settings.max_points)
    if keys is not None:
        app.add_middleware(KeyGuard, keys=keys, settings=settings, metrics=app_metrics)
    app.add_middleware(Cors, origins=settings.cors_origins, keys=keys is not None)
    app.add_middleware(RequestContext, lifecycle=lifecycle, retry_after=settings.retry_after_s,
                       fault_injection=settings.fault_injection)
    app.add_middleware(SecurityHeaders)
    app.add_middleware(MetricsMiddleware, metrics=app_metrics)
    return app
