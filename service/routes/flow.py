"""``POST /v1/flow``: the dense forward flow a -> b in any format of ``reglib.outputs.FLOW_FORMATS`` (.npy, .flo,
an ITK displacement field .mha, .nrrd, .nii, .nii.gz for medical tools), or its colour picture as PNG."""
from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response

from .. import jobs
from ..deps import PoolDep, SettingsDep
from ..openapi import PROBLEM_RESPONSES, multipart_openapi
from ..problems import INVALID_INPUT, Problem
from ..schemas import FLOW_ANSWERS, FlowFields
from ..uploads import read_upload

router = APIRouter(tags=["images"])

# the displacement fields have no registered media type of their own
MEDIA = {fmt: {"npy": "application/x-npy", "flo": "application/x-flo", "png": "image/png"}.get(
    fmt, "application/octet-stream") for fmt in FLOW_ANSWERS}


_BY_ACCEPT = {"application/x-npy": "npy", "application/octet-stream": "npy", "application/x-flo": "flo",
              "image/png": "png"}


def format_from_accept(accept: str | None) -> str:
    """The first listed media type we serve (q-values are not ranked); ``*/*`` or none -> npy."""
    for part in (accept or "").split(","):
        media = part.split(";")[0].strip().lower()
        if media in _BY_ACCEPT:
            return _BY_ACCEPT[media]
    return "npy"


@router.post("/v1/flow", summary="Dense flow a -> b: .npy, .flo, .mha, .nrrd, .nii, .nii.gz or colour PNG",
             response_class=Response,
             responses={200: {"content": {m: {} for m in MEDIA.values()},
                              "description": "(H_a, W_a, 2) float32 of (dx, dy) (an ITK displacement "
                                             "field for mha / nrrd / nii / nii.gz), or its colour picture"},
                        **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(FlowFields, "image_a, image_b, match options and `format`"))
async def flow(request: Request, settings: SettingsDep, pool: PoolDep) -> Response:
    """`reglib.dense_flow(match.transform, a.shape[:2])`; format by the `format` field (form or query) or Accept."""
    query = dict(request.query_params)
    unknown = sorted(set(query) - {"format"})
    if unknown:
        raise Problem(422, INVALID_INPUT, f"unknown query parameter(s) {unknown}; only `format` is read there")
    upload = await read_upload(request, settings, FlowFields, extra=query)
    fmt = upload.fields.format or format_from_accept(request.headers.get("accept"))
    blob = await pool.run(jobs.flow_job, upload.image_a, upload.image_b, upload.request, fmt)
    return Response(blob, media_type=MEDIA[fmt],
                    headers={"Content-Disposition": f'attachment; filename="flow.{fmt}"'})
