"""``POST /v1/match``: two images -> putative matches, inliers, scores and the transform."""
from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse

from .. import jobs
from ..config import Settings
from ..deps import PROBLEM_RESPONSES, get_pool, get_settings
from ..pool import WorkPool
from ..schemas import MatchResponse
from ..uploads import multipart_openapi, read_upload

router = APIRouter(tags=["images"])


@router.post("/v1/match", summary="Match two images (SIFT, multimodal or shape-context features + L2E/VFC)", response_model=None,
             responses={200: {"model": MatchResponse}, **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(Settings(), None,
                                             "image_a, image_b and the fields of a reglib.MatchRequest"))
async def match(request: Request, settings: Settings = Depends(get_settings),
                pool: WorkPool = Depends(get_pool)) -> JSONResponse:
    """`reglib.MatchRequest.from_fields(form).run(a, b).to_dict()`: `reglib.match_images` with the form's fields."""
    data_a, data_b, match_request, _ = await read_upload(request, settings)
    result = await pool.run(jobs.match_job, data_a, data_b, match_request.to_fields())
    return JSONResponse(result)
