"""``POST /v1/match/bundle``: one match and every file of it (warped, overlay, flow, confidence) in one answer.

The web page asks this once per click, where it used to ask ``/v1/match``, ``/v1/warp``, ``/v1/flow``
and ``/v1/confidence``, each of which computes the match again. The files are base64 in a JSON body,
each the bytes its single endpoint answers for the same form.
"""
from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field

from .. import jobs
from ..deps import PoolDep, SettingsDep
from ..openapi import PROBLEM_RESPONSES, multipart_openapi
from ..schemas import MatchResponse
from ..uploads import read_upload

router = APIRouter(tags=["images"])

#: The files of a bundle, in the order they are listed; ``confidence.png`` only with a confidence map.
BUNDLE_FILES = ("warped.png", "overlay.png", "flow.png", "flow.flo", "confidence.png")


class BundleFields(BaseModel):
    """The form field of ``/v1/match/bundle`` beside the match request's."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    alpha: float = Field(default=0.5, ge=0, le=1, description="weight of warped b in overlay.png (as /v1/warp's)")


class BundleFiles(BaseModel):
    """The files, base64: each equals its single endpoint's answer to the same form."""

    model_config = ConfigDict(populate_by_name=True)
    warped_png: str = Field(alias="warped.png", description="/v1/warp: b warped into a's frame (PNG)")
    overlay_png: str = Field(alias="overlay.png", description="/v1/warp with overlay=true and this alpha (PNG)")
    flow_png: str = Field(alias="flow.png", description="/v1/flow?format=png: the flow's colour picture")
    flow_flo: str = Field(alias="flow.flo", description="/v1/flow?format=flo: the forward flow, Middlebury .flo")
    confidence_png: str | None = Field(default=None, alias="confidence.png", description=(
        "/v1/confidence?format=png: round(255 x confidence); the key is absent when the match has no "
        "confidence map"))


class BundleResponse(BaseModel):
    match: MatchResponse = Field(description="exactly the answer of /v1/match to the same form")
    files: BundleFiles


@router.post("/v1/match/bundle", summary="Match two images once and answer the match with all its files (base64)",
             response_model=None, responses={200: {"model": BundleResponse}, **PROBLEM_RESPONSES},
             openapi_extra=multipart_openapi(BundleFields, "image_a, image_b, the fields of a reglib.MatchRequest "
                                                           "and `alpha`"))
async def bundle(request: Request, settings: SettingsDep, pool: PoolDep) -> Response:
    """`/v1/match`'s answer and, from the same match, the bytes of `/v1/warp` (plain and overlay), `/v1/flow`
    (PNG and .flo) and `/v1/confidence` (PNG), base64-encoded."""
    upload = await read_upload(request, settings, BundleFields)
    body = await pool.run(jobs.bundle_job, upload.image_a, upload.image_b, upload.request, upload.fields.alpha)
    return Response(body, media_type="application/json")
