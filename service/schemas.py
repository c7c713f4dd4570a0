"""Request and response bodies of the JSON endpoints, and the image endpoints' own form fields.

(The match request's form fields are derived from the library's declarations: see ``uploads``.)

Request models forbid unknown keys (a misspelled option is a 422, never silently ignored) and
non-finite numbers. Options that the library owns (``options`` dicts) are passed through as given
and checked by the library itself, which names the bad field.
"""
from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from reglib import REASONS, Reason
from reglib.outputs import FLOW_FORMATS
from reglib.registration import METHODS, methods_taking
from reglib.robust import METHODS as FILTER_METHODS

__all__ = ["FLOW_ANSWERS", "FilterRequest", "FilterResponse", "RegisterRequest", "RegisterResponse", "MatchResponse",
           "Transform", "MatchFields", "WarpFields", "FlowFields", "ConfidenceFields", "Seed", "is_scan_row"]

# what /v1/flow answers: the flow files of every other surface (reglib.outputs.FLOW_FORMATS), and its picture
FLOW_ANSWERS: tuple[str, ...] = (*FLOW_FORMATS, "png")

Point = Annotated[list[float], Field(min_length=2, max_length=3)]
OptionalPoint = Annotated[list[float], Field(min_length=3, max_length=3)] | None


def is_scan_row(row: Any) -> bool:
    """Whether ``row`` is a row of an organized (H, W, 3) scan (points or nulls), not one (x, y[, z]) point."""
    return isinstance(row, list) and bool(row) and (row[0] is None or isinstance(row[0], list))
Seed = Annotated[int, Field(ge=0, le=2**53, description="random seed (default 0), recorded in the answer")]

# points of the OpenAPI examples; list[Any]: json_schema_extra takes JSON values and list is invariant
_SRC: list[Any] = [[10.0, 12.0], [200.0, 40.0], [130.0, 300.0], [410.0, 220.0], [50.0, 380.0], [300.0, 90.0],
                   [250.0, 250.0], [90.0, 150.0], [360.0, 360.0], [170.0, 60.0]]
_DST: list[Any] = [[x + 12.0, y - 4.0] for x, y in _SRC[:8]] + [[5.0, 400.0], [420.0, 10.0]]




def _reason(applies: str, *, required: bool = True) -> Any:
    """The ``reason`` field of a response: null, or a code of the library's list; ``x-reasons`` says what
    each code means, in words (the page shows those)."""
    return Field(default=... if required else None, description=f"null when converged; else why not ({applies}): "
                 + "; ".join(f"{code}: {text}" for code, text in REASONS.items()),
                 json_schema_extra={"x-reasons": dict(REASONS.items())})


class _Request(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Transform(BaseModel):
    """The transform JSON of CONTRACTS.md (``KernelWarp.to_dict()``)."""

    model_config = ConfigDict(extra="allow")
    type: Literal["kernel_warp"]
    version: int
    dim: int
    src_mean: list[float]
    src_scale: float
    dst_mean: list[float]
    dst_scale: float
    linear: dict[str, Any] | None
    beta: float
    centers: list[list[float]]
    weights: list[list[float]]


class FilterRequest(_Request):
    """Putative matches: row i of ``src`` (x, y[, z]) is matched to row i of ``dst``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={
        "examples": [{"src": _SRC, "dst": _DST, "method": "l2e", "options": {"linear": "affine"}, "seed": 0}]})
    src: list[Point] = Field(description="(N, D) points, D in {2, 3}")
    dst: list[Point] = Field(description="(N, D) points, the same shape as src")
    # A plain string, checked by the route against the library's list so that a bad name is answered in the
    # library's words (`method` must be one of [...]); the OpenAPI schema still lists the names.
    method: str = Field(default="l2e", description="the estimator (reglib.robust.METHODS)",
                        json_schema_extra={"enum": list(FILTER_METHODS)})
    options: dict[str, Any] | None = Field(
        default=None, description="fields of reglib.L2EOptions or reglib.VFCOptions (per method)")
    seed: Seed = 0


class FilterResponse(BaseModel):
    n_matches: int
    n_inliers: int
    inliers: list[int] = Field(description="ascending indices into src/dst of the kept matches")
    scores: list[float] = Field(description="(N,) in [0, 1]")
    transform: Transform
    converged: bool
    reason: Reason | None = _reason("the estimator's codes")
    sigma: float = Field(description="residual scale of the true matches, in dst units")
    n_iter: int
    method: str
    seed: int
    stopped: Literal["tolerance", "iteration_cap"] | None = Field(
        default=None, description="why the iterations ended (not a verdict: converged is); absent when nothing ran")
    timings_ms: dict[str, float]


# the registration methods that take colors / each set's normals, from the library's method table
_COLORS, _MODEL_NORMALS, _TGT_NORMALS = (" / ".join(methods_taking(extra))
                                         for extra in ("colors", "model_normals", "target_normals"))


class RegisterRequest(_Request):
    """Two point sets without correspondences: ``model`` is moved onto ``target``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={
        "examples": [{"model": _SRC, "target": [[x * 1.1 + 5.0, y * 0.95 - 3.0] for x, y in _SRC],
                      "method": "l2e", "options": None, "seed": 0}]})
    model: list[Point] | list[list[OptionalPoint]] = Field(
        description="(N, D) points, D in {2, 3}; or an organized scan (H, W, 3) with null where nothing was seen")
    target: list[Point] | list[list[OptionalPoint]] = Field(
        description="(M, D) points, the same D; or an organized scan (H, W, 3)")
    # A plain string, checked by the route against the library's method table so that a bad name is answered
    # in the library's words (`method` must be one of [...]); the OpenAPI schema still lists the names.
    method: str = Field(default="l2e", description="the registration method (reglib.registration.METHODS)",
                        json_schema_extra={"enum": list(METHODS)})
    options: dict[str, Any] | None = Field(default=None, description="options of the registration method")
    seed: Seed = 0
    model_colors: list[Any] | None = Field(default=None, description=f"{_COLORS}: RGB in [0, 1] per model point")
    target_colors: list[Any] | None = Field(default=None, description=f"{_COLORS}: RGB in [0, 1] per target point")
    model_normals: list[Any] | None = Field(default=None, description=f"{_MODEL_NORMALS}: unit normal per model point")
    target_normals: list[Any] | None = Field(default=None, description=f"{_TGT_NORMALS}: unit normal per target point")


class RegisterResponse(BaseModel):
    registered: list[list[float] | None] = Field(
        description="(N, D): the model moved by the transform (null where an organized scan has no point)")
    correspondence: list[int] = Field(description="(N,) index into target of each model point, -1 for none "
                                      "(an organized scan: H * W entries, row-major)")
    transform: Transform
    converged: bool
    reason: Reason | None = _reason("a registration's codes", required=False)
    n_iter: int
    method: str
    seed: int
    fitness: float | None = Field(default=None, ge=0, le=1, description="share of the model's points with a target "
                                  "point within reach of their registered position (Open3D's fitness)")
    inlier_rmse: float | None = Field(default=None, ge=0, description="RMS distance of those points to their "
                                      "nearest target point, in the target's units")
    matrix: list[list[float]] | None = Field(
        default=None, description="(D+1, D+1) homogeneous matrix [[A, t], [0, 1]] of the map in the caller's units "
        "(registered = model A^T + t) for the rigid, similarity and affine methods; null for the non-rigid ones")
    timings_ms: dict[str, float]


class MatchResponse(BaseModel):
    model_config = ConfigDict(extra="allow")
    n_matches: int
    n_inliers: int
    src: list[list[float]] = Field(description="(N, 2) putative match points in image a (x = column)")
    dst: list[list[float]] = Field(description="(N, 2) the matched points in image b")
    inliers: list[int]
    scores: list[float]
    transform: Transform
    converged: bool
    reason: Reason | None = _reason("the estimator's codes, or unsupported")
    seed: int
    timings_ms: dict[str, float]


class MatchFields(_Request):
    """``/v1/match`` has no form fields beside the match request's."""


class WarpFields(_Request):
    """The form fields of ``/v1/warp`` beside the match request's."""

    overlay: bool = Field(default=False, description="blend the warped image b over image a")
    alpha: float = Field(default=0.5, ge=0, le=1, description="weight of warped b in the overlay")
    interpolation: Literal["linear", "nearest"] = "linear"


class FlowFields(_Request):
    """The form field of ``/v1/flow`` beside the match request's."""

    format: Literal[FLOW_ANSWERS] | None = Field(  # type: ignore[valid-type]  # the one list, read at run time
        default=None, description="npy (float32 (H, W, 2) dx, dy), flo (Middlebury), mha (MetaImage), nrrd, nii or "
                                  "nii.gz (NIfTI-1): an ITK displacement field (2-D, 2-component float32 vectors in "
                                  "pixels, spacing 1, origin 0, identity direction: reglib.io.write_flow), or png "
                                  "(colour picture); default from Accept, else npy")


class ConfidenceFields(_Request):
    """The form field of ``/v1/confidence`` beside the match request's."""

    format: Literal["npy", "png"] = Field(default="png", description="png (8-bit grey, round(255 x confidence)) "
                                          "or npy ((H_a, W_a) float32 in [0, 1])")
