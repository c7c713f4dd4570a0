"""The routes' dependencies, as ``Annotated`` aliases: the app's settings, pool, lifecycle and metrics.

A route declares ``settings: SettingsDep`` and FastAPI hands it ``request.app.state.settings``;
tests override a getter with ``app.dependency_overrides[get_settings] = ...``. Each app has its own
(``create_app`` puts them on ``app.state``), so nothing here is read at import time.
"""
from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from .config import Settings
from .lifecycle import Lifecycle
from .metrics import Metrics
from .pool import WorkPool

__all__ = ["get_settings", "get_pool", "get_lifecycle", "get_metrics", "SettingsDep", "PoolDep", "LifecycleDep",
           "MetricsDep"]


def get_settings(request: Request) -> Settings:
    """The settings of the app serving ``request``."""
    return request.app.state.settings  # type: ignore[no-any-return]  # Starlette's State is untyped


def get_pool(request: Request) -> WorkPool:
    """The work pool of the app serving ``request``."""
    return request.app.state.pool  # type: ignore[no-any-return]  # Starlette's State is untyped


def get_lifecycle(request: Request) -> Lifecycle:
    """The drain state of the app serving ``request``."""
    return request.app.state.lifecycle  # type: ignore[no-any-return]  # Starlette's State is untyped


def get_metrics(request: Request) -> Metrics:
    """The metrics registry of the app serving ``request``."""
    return request.app.state.metrics  # type: ignore[no-any-return]  # Starlette's State is untyped


SettingsDep = Annotated[Settings, Depends(get_settings)]
PoolDep = Annotated[WorkPool, Depends(get_pool)]
LifecycleDep = Annotated[Lifecycle, Depends(get_lifecycle)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
