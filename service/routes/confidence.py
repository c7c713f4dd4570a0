"""``POST /v1/confidence``: how well the match's flow is supported at each pixel of a, as .npy or PNG."""
from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from .. import jobs
from ..config import Settings
from ..deps import PROBLEM_RESPONSES, get_pool, get_settings
from ..pool import WorkPool
from ..schemas import ConfidenceFields
from ..uploads import multipart_openapi, read_upload

router = APIRouter(tags=["images"])

MEDIA = {"npy": "application/x-npy", "png": "image/png"}


@router.post("/v1/confidence", summary="Confidence map of the match's flow: .npy (float32 in [0, 1]) or grey PNG",
             response_class=Response,
             responses={200: {"content": {m: {} for m in MEDIA.values()},
                              "description": "(H_a, W_a): about 1 where the flow follows the images, 0 where it is "
                                             "only extrapolated"},
                        **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(Settings(), ConfidenceFields, "image_a, image_b, match options and "
                                                                           "`format`"))
async def confidence(request: Request, settings: Settings = Depends(get_settings),
                     pool: WorkPool = Depends(get_pool)) -> Response:
    """`ImageMatch.confidence` of `reglib.MatchRequest.from_fields(form).run(a, b)`; PNG = round(255 x map)."""
    data_a, data_b, match_request, fields = await read_upload(request, settings, ConfidenceFields)
    assert fields is not None
    blob = await pool.run(jobs.confidence_job, data_a, data_b, match_request.to_fields(), fields.format)
    return Response(blob, media_type=MEDIA[fields.format],
                    headers={"Content-Disposition": f'attachment; filename="confidence.{fields.format}"'})
