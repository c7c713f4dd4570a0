"""``POST /v1/register``: register two point sets without known correspondences."""
from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse

from .. import jobs
from ..config import Settings
from ..deps import PROBLEM_RESPONSES, get_pool, get_settings
from ..pool import WorkPool
from ..schemas import RegisterRequest, RegisterResponse
from .filter import check_points

router = APIRouter(tags=["points"])


@router.post("/v1/register", summary="Register a model point set onto a target (2-D or 3-D)", response_model=None,
             responses={200: {"model": RegisterResponse}, **PROBLEM_RESPONSES})
async def register(body: RegisterRequest, settings: Settings = Depends(get_settings),
                   pool: WorkPool = Depends(get_pool)) -> JSONResponse:
    """`reglib.register_points(model, target, method=..., options=..., rng=seed, ...).to_dict()`."""
    check_points(settings, model=body.model, target=body.target)
    extras = {"model_colors": body.model_colors, "target_colors": body.target_colors,
              "model_normals": body.model_normals, "target_normals": body.target_normals}
    result = await pool.run(jobs.register_job, body.model, body.target, body.method, body.options, body.seed, extras)
    return JSONResponse(result)
