"""``POST /v1/warp``: image b warped into image a's frame (or blended over a), as PNG."""
from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response

from .. import jobs
from ..deps import PoolDep, SettingsDep
from ..openapi import PROBLEM_RESPONSES, multipart_openapi
from ..schemas import WarpFields
from ..uploads import read_upload

router = APIRouter(tags=["images"])


@router.post("/v1/warp", summary="Warp image b onto image a (PNG)", response_class=Response,
             responses={200: {"content": {"image/png": {}}, "description": "PNG of the size of image a"},
                        **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(WarpFields, "image_a, image_b, match options and overlay options"))
async def warp(request: Request, settings: SettingsDep, pool: PoolDep) -> Response:
    """`reglib.warp_image(b, match.transform, a.shape[:2])` (or `reglib.visualize.overlay` of it on a)."""
    upload = await read_upload(request, settings, WarpFields)
    fields = upload.fields
    png = await pool.run(jobs.warp_job, upload.image_a, upload.image_b, upload.request, fields.overlay, fields.alpha,
                         fields.interpolation)
    return Response(png, media_type="image/png")
