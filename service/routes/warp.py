"""``POST /v1/warp``: image b warped into image a's frame (or blended over a), as PNG."""
from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from .. import jobs
from ..config import Settings
from ..deps import PROBLEM_RESPONSES, get_pool, get_settings
from ..pool import WorkPool
from ..schemas import WarpFields
from ..uploads import multipart_openapi, read_upload

router = APIRouter(tags=["images"])


@router.post("/v1/warp", summary="Warp image b onto image a (PNG)", response_class=Response,
             responses={200: {"content": {"image/png": {}}, "description": "PNG of the size of image a"},
                        **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(Settings(), WarpFields,
                                             "image_a, image_b, match options and overlay options"))
async def warp(request: Request, settings: Settings = Depends(get_settings),
               pool: WorkPool = Depends(get_pool)) -> Response:
    """`reglib.warp_image(b, match.transform, a.shape[:2])` (or `reglib.visualize.overlay` of it on a)."""
    data_a, data_b, match_request, fields = await read_upload(request, settings, WarpFields)
    assert fields is not None
    png = await pool.run(jobs.warp_job, data_a, data_b, match_request.to_fields(), fields.overlay, fields.alpha,
                         fields.interpolation)
    return Response(png, media_type="image/png")
