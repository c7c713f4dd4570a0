"""``POST /v1/filter``: keep the putative matches that agree with one smooth transformation."""
from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from reglib.robust import METHODS

from .. import jobs
from ..deps import PoolDep, SettingsDep
from ..limits import check_points
from ..openapi import PROBLEM_RESPONSES
from ..problems import INVALID_INPUT, Problem
from ..schemas import FilterRequest, FilterResponse

router = APIRouter(tags=["points"])


@router.post("/v1/filter", summary="Robustly filter putative matches (L2E or VFC)", response_model=None,
             responses={200: {"model": FilterResponse}, **PROBLEM_RESPONSES})
async def filter_matches(body: FilterRequest, settings: SettingsDep, pool: PoolDep) -> JSONResponse:
    """`reglib.filter_matches(src, dst, method=..., options=..., rng=seed)`; `inliers` are indices."""
    if body.method not in METHODS:  # in the library's words (filter_matches' own check), before any work
        raise Problem(422, INVALID_INPUT, f"`method` must be one of {list(METHODS)}, got {body.method!r}")
    check_points(settings, src=body.src, dst=body.dst)
    result = await pool.run(jobs.filter_job, body.src, body.dst, body.method, body.options, body.seed)
    return JSONResponse(result)
