"""``POST /v1/filter``: keep the putative matches that agree with one smooth transformation."""
from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse

from .. import jobs
from ..config import Settings
from ..deps import PROBLEM_RESPONSES, get_pool, get_settings
from ..pool import WorkPool
from ..problems import TOO_LARGE, Problem
from ..schemas import FilterRequest, FilterResponse, is_scan_row

router = APIRouter(tags=["points"])


def _count(points: list) -> int:
    """Points in a set: rows of (N, D), or the pixels of an organized (H, W, 3) scan."""
    return sum(len(row) if is_scan_row(row) else 1 for row in points)


def check_points(settings: Settings, **sets: list) -> None:
    for name, points in sets.items():
        n = _count(points)
        if n > settings.max_points:
            raise Problem(413, TOO_LARGE, f"`{name}` has {n} points, over the limit of {settings.max_points}")


@router.post("/v1/filter", summary="Robustly filter putative matches (L2E or VFC)", response_model=None,
             responses={200: {"model": FilterResponse}, **PROBLEM_RESPONSES})
async def filter_matches(body: FilterRequest, settings: Settings = Depends(get_settings),
                         pool: WorkPool = Depends(get_pool)) -> JSONResponse:
    """`reglib.filter_matches(src, dst, method=..., options=..., rng=seed)`; `inliers` are indices."""
    check_points(settings, src=body.src, dst=body.dst)
    result = await pool.run(jobs.filter_job, body.src, body.dst, body.method, body.options, body.seed)
    return JSONResponse(result)
