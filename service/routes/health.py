"""``/livez`` (the process answers) and ``/readyz`` (every configured worker is alive and the app is not draining)."""
from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response

from ..deps import LifecycleDep, PoolDep
from ..problems import NOT_READY, problem_response

router = APIRouter(tags=["health"])


@router.get("/livez", summary="Liveness: the server process answers")
async def livez() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz", summary="Readiness: every worker is alive and the service is not shutting down",
            responses={503: {"description": "starting, shutting down, or a worker is being replaced"}})
async def readyz(pool: PoolDep, lifecycle: LifecycleDep) -> Response:
    if lifecycle.draining:
        return problem_response(503, NOT_READY, "the service is shutting down",
                                headers={"Retry-After": str(pool.retry_after)})
    if not pool.ready:
        detail = (f"{pool.alive} of {pool.workers} workers are alive; the others are being replaced"
                  if pool.pending or pool.alive else "the compute pool is not ready")
        return problem_response(503, NOT_READY, detail, headers={"Retry-After": str(pool.retry_after)},
                                extra={"workers": pool.workers, "alive": pool.alive})
    return JSONResponse({"status": "ready", "workers": pool.workers, "alive": pool.alive, "pending": pool.pending})
