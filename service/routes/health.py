"""``/livez`` (the process answers) and ``/readyz`` (the compute pool is up)."""
from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse, Response

from ..deps import get_pool
from ..pool import WorkPool
from ..problems import NOT_READY, problem_response

router = APIRouter(tags=["health"])


@router.get("/livez", summary="Liveness: the server process answers")
async def livez() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz", summary="Readiness: the compute pool is up",
            responses={503: {"description": "the pool is starting, stopping or restarting"}})
async def readyz(pool: WorkPool = Depends(get_pool)) -> Response:
    if not pool.ready:
        return problem_response(503, NOT_READY, "the compute pool is not ready",
                                headers={"Retry-After": str(pool.retry_after)})
    return JSONResponse({"status": "ready", "workers": pool.workers, "pending": pool.pending})
