"""``POST /v1/confidence``: how well the match's flow is supported at each pixel of a, as .npy or PNG."""
from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response

from .. import jobs
from ..deps import PoolDep, SettingsDep
from ..openapi import PROBLEM_RESPONSES, multipart_openapi
from ..schemas import ConfidenceFields
from ..uploads import read_upload

router = APIRouter(tags=["images"])

MEDIA = {"npy": "application/x-npy", "png": "image/png"}


@router.post("/v1/confidence", summary="Confidence map of the match's flow: .npy (float32 in [0, 1]) or grey PNG",
             response_class=Response,
             responses={200: {"content": {m: {} for m in MEDIA.values()},
                              "description": "(H_a, W_a): about 1 where the flow follows the images, 0 where it is "
                                             "only extrapolated"},
                        **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(ConfidenceFields, "image_a, image_b, match options and "
                                                                           "`format`"))
async def confidence(request: Request, settings: SettingsDep, pool: PoolDep) -> Response:
    """`ImageMatch.confidence` of `reglib.MatchRequest.from_fields(form).run(a, b)`; PNG = round(255 x map)."""
    upload = await read_upload(request, settings, ConfidenceFields)
    fmt = upload.fields.format
    blob = await pool.run(jobs.confidence_job, upload.image_a, upload.image_b, upload.request, fmt)
    return Response(blob, media_type=MEDIA[fmt],
                    headers={"Content-Disposition": f'attachment; filename="confidence.{fmt}"'})
