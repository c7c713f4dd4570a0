"""``POST /v1/match``: two images -> putative matches, inliers, scores and the transform."""
from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from .. import jobs
from ..deps import PoolDep, SettingsDep
from ..openapi import PROBLEM_RESPONSES, multipart_openapi
from ..schemas import MatchFields, MatchResponse
from ..uploads import read_upload

router = APIRouter(tags=["images"])


@router.post("/v1/match", summary="Match two images (SIFT, multimodal or shape-context features + L2E/VFC)",
             response_model=None, responses={200: {"model": MatchResponse}, **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(MatchFields, "image_a, image_b and the fields of a reglib.MatchRequest"))
async def match(request: Request, settings: SettingsDep, pool: PoolDep) -> JSONResponse:
    """`reglib.MatchRequest.from_fields(form).run(a, b).to_dict()`: `reglib.match_images` with the form's fields."""
    upload = await read_upload(request, settings, MatchFields)
    result = await pool.run(jobs.match_job, upload.image_a, upload.image_b, upload.request)
    return JSONResponse(result)
