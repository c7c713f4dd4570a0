"""Dependencies shared by the routers: the app's settings and its work pool (overridable in tests)."""
from __future__ import annotations

from fastapi import Request

from .config import Settings
from .pool import WorkPool

__all__ = ["get_settings", "get_pool", "PROBLEM_RESPONSES"]


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_pool(request: Request) -> WorkPool:
    return request.app.state.pool


def _problem(description: str) -> dict[str, object]:
    return {"description": description, "content": {"application/problem+json": {"schema": {
        "type": "object", "properties": {"type": {"type": "string"}, "title": {"type": "string"},
                                         "status": {"type": "integer"}, "detail": {"type": "string"}}}}}}


PROBLEM_RESPONSES: dict[int | str, dict[str, object]] = {
    400: _problem("body or image cannot be parsed or decoded"),
    413: _problem("over the byte, pixel or point limit, or the job needed more than a worker's memory cap"),
    415: _problem("media type or image format not allowed"),
    422: _problem("invalid input (shapes, NaN, unknown or out-of-range option) or the estimation failed"),
    429: _problem("work queue full; see Retry-After"),
    503: _problem("not ready (starting, replacing a worker, or shutting down); see Retry-After"),
    504: _problem("the computation ran past its time limit"),
    500: _problem("the request crashed a worker process twice (worker-crashed), or a fault of ours (internal)"),
}
