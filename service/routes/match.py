"""``POST /v1/match``: two images -> putative matches, inliers, scores and the transform."""
from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse

from .. import jobs
from ..config import Settings
from ..deps import PROBLEM_RESPONSES, get_pool, get_settings
from ..pool import WorkPool
from ..schemas import MatchFields, MatchResponse
from ..uploads import multipart_openapi, read_upload

router = APIRouter(tags=["images"])


def options_of(fields: MatchFields) -> dict[str, object]:
    """The library's keyword arguments for the fields that were given (absent ones keep their defaults)."""
    given = fields.model_dump(include=set(MatchFields.model_fields), exclude_none=True)
    given["seed"] = fields.seed
    return given


@router.post("/v1/match", summary="Match two images (SIFT or shape context + L2E/VFC)", response_model=None,
             responses={200: {"model": MatchResponse}, **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(MatchFields, "image_a, image_b and options of reglib.match_images"))
async def match(request: Request, settings: Settings = Depends(get_settings),
                pool: WorkPool = Depends(get_pool)) -> JSONResponse:
    """`reglib.match_images(a, b, features=..., method=..., options=..., rng=seed).to_dict()`."""
    data_a, data_b, fields = await read_upload(request, settings, MatchFields)
    result = await pool.run(jobs.match_job, data_a, data_b, options_of(fields), settings.max_pixels)
    return JSONResponse(result)
