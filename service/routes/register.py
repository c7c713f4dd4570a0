"""``POST /v1/register``: register two point sets without known correspondences."""
from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from reglib.registration import method_spec

from .. import jobs
from ..deps import PoolDep, SettingsDep
from ..limits import check_points
from ..openapi import PROBLEM_RESPONSES
from ..schemas import RegisterRequest, RegisterResponse

router = APIRouter(tags=["points"])


@router.post("/v1/register", summary="Register a model point set onto a target (2-D or 3-D)", response_model=None,
             responses={200: {"model": RegisterResponse}, **PROBLEM_RESPONSES})
async def register(body: RegisterRequest, settings: SettingsDep, pool: PoolDep) -> JSONResponse:
    """`reglib.register_points(model, target, method=..., options=..., rng=seed, ...).to_dict()`."""
    method_spec(body.method)  # an unknown name: InputError "`method` must be one of [...]" -> 422, before any work
    check_points(settings, model=body.model, target=body.target)
    extras = {"model_colors": body.model_colors, "target_colors": body.target_colors,
              "model_normals": body.model_normals, "target_normals": body.target_normals}
    result = await pool.run(jobs.register_job, body.model, body.target, body.method, body.options, body.seed, extras)
    return JSONResponse(result)
