"""What the workers run: plain functions of picklable arguments, returning JSON-ready dicts or bytes.

These run in the pool's processes (see :mod:`service.pool`); they import reglib's functions lazily,
call one library function, and answer with the library's own JSON form (``to_dict()``) plus the
shell's ``timings_ms``, so each answer is the library's answer for the same inputs and seed. The
image jobs take the :class:`~reglib.MatchRequest` the service parsed from the form (a frozen value
that pickles), so the form is parsed once, on the event loop, and never again in the worker.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from reglib import ImageMatch, MatchRequest
from reglib.errors import ImageTooLarge, InputError, UnsupportedFormat

from .pool import UndecodableImage
from .schemas import is_scan_row

__all__ = ["filter_job", "register_job", "match_job", "warp_job", "flow_job", "confidence_job", "bundle_job"]


def _ms(start: float) -> float:
    return (time.perf_counter() - start) * 1e3


def filter_job(src: list[Any], dst: list[Any], method: Literal["l2e", "vfc"], options: dict[str, Any] | None,
               seed: int) -> dict[str, Any]:
    """``reglib.filter_matches(...).to_dict()`` plus ``timings_ms``."""
    from reglib import filter_matches

    start = time.perf_counter()
    body = filter_matches(src, dst, method=method, options=options, rng=seed).to_dict()
    body["timings_ms"] = {"filter": _ms(start)}
    return body


def _points(value: Any, name: str) -> Any:
    """An organized scan's null pixels as NaN rows (the one place NaN is valid input); else as given."""
    if isinstance(value, list) and value and is_scan_row(value[0]):
        try:
            return np.array([[[np.nan] * 3 if p is None else p for p in row] for row in value], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"`{name}` looks like an organized scan (rows of points, null where nothing was "
                             "seen) but its rows are not all points of 3 numbers or null") from None
    return value


def register_job(model: Any, target: Any, method: str, options: dict[str, Any] | None, seed: int,
                 extras: dict[str, Any] | None = None) -> dict[str, Any]:
    """``reglib.register_points(...).to_dict()`` plus ``timings_ms``; ``extras``: colours and normals."""
    from reglib import register_points

    start = time.perf_counter()
    try:
        extra = {k: _points(v, k) for k, v in (extras or {}).items() if v is not None}
        result = register_points(_points(model, "model"), _points(target, "target"),
                                 method=method,  # type: ignore[arg-type]  # a plain str: register_points checks it
                                 options=options, rng=seed, **extra)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"the point sets are not arrays of numbers: {exc}") from None
    body = result.to_dict()
    body["timings_ms"] = {"register": _ms(start)}
    return body


def _decode(data: bytes, max_pixels: int, name: str) -> np.ndarray:
    from reglib.io import read_image

    try:
        return read_image(data, max_pixels=max_pixels, name=name)
    except (ImageTooLarge, UnsupportedFormat):
        raise
    except InputError as exc:
        raise UndecodableImage(str(exc)) from None


@dataclass(frozen=True, eq=False)
class _Matched:
    """Both decoded images, the match of them, and how long decoding took."""

    image_a: np.ndarray
    image_b: np.ndarray
    match: ImageMatch
    decode_ms: float


def _match(data_a: bytes, data_b: bytes, request: MatchRequest) -> _Matched:
    """Decode both images (at the request's pixel limit) and run the request on them."""
    start = time.perf_counter()
    limit = request.options.max_pixels
    image_a = _decode(data_a, limit, "image_a")
    image_b = _decode(data_b, limit, "image_b")
    decode_ms = _ms(start)
    return _Matched(image_a, image_b, request.run(image_a, image_b), decode_ms)


def _body(matched: _Matched) -> dict[str, Any]:
    """The match's JSON form; the decode time joins ``timings_ms``."""
    body = matched.match.to_dict()
    body["timings_ms"] = {"decode": matched.decode_ms, **body.get("timings_ms", {})}
    return body


def _warped(matched: _Matched, interpolation: Literal["linear", "nearest"]) -> np.ndarray:
    """Image b warped into a's frame by the match's transform."""
    from reglib import warp_image

    warped, _valid = warp_image(matched.image_b, matched.match.transform, matched.image_a.shape[:2],
                                interpolation=interpolation)
    return warped


def _flow(matched: _Matched) -> np.ndarray:
    """The match's dense forward flow (H_a, W_a, 2) float32 of (dx, dy)."""
    from reglib import dense_flow

    return np.asarray(dense_flow(matched.match.transform, matched.image_a.shape[:2]), dtype=np.float32)


def _confidence_png(confidence: Any) -> bytes:
    """The grey PNG of ``reglib match --out``'s ``confidence.png`` (``round(255 * confidence)``)."""
    from reglib.io import encode_png

    conf = np.asarray(confidence, dtype=np.float32)
    return encode_png(np.round(np.clip(conf, 0.0, 1.0) * 255.0).astype(np.uint8))


def match_job(data_a: bytes, data_b: bytes, request: MatchRequest) -> dict[str, Any]:
    """``request.run(a, b).to_dict()``; the decode time joins ``timings_ms``."""
    return _body(_match(data_a, data_b, request))


def warp_job(data_a: bytes, data_b: bytes, request: MatchRequest, overlay: bool, alpha: float,
             interpolation: Literal["linear", "nearest"]) -> bytes:
    """PNG of b warped onto a by the match's transform, or blended over a (weight ``alpha``) with ``overlay``."""
    from reglib.io import encode_png
    from reglib.visualize import overlay as blend

    matched = _match(data_a, data_b, request)
    warped = _warped(matched, interpolation)
    return encode_png(blend(matched.image_a, warped, alpha) if overlay else _png_bands(warped))


def _png_bands(image: np.ndarray) -> np.ndarray:
    """``image`` as it is when PNG holds its bands (1, 3 or 4), else its RGB picture (a PNG answer is a picture)."""
    from reglib.visualize import to_rgb_uint8

    return image if image.ndim == 2 or image.shape[2] in (3, 4) else to_rgb_uint8(image, "warped")


def flow_job(data_a: bytes, data_b: bytes, request: MatchRequest, fmt: str) -> bytes:
    """The match's dense forward flow (H_a, W_a, 2) float32 of (dx, dy) as ``.npy``, ``.flo``, its colour PNG,
    or an ITK displacement field ``.mha`` / ``.nrrd`` / ``.nii`` / ``.nii.gz`` (``reglib.io.write_flow``'s bytes)."""
    from reglib.io import encode_flow, encode_png
    from reglib.visualize import flow_to_color

    flow = _flow(_match(data_a, data_b, request))
    if fmt == "png":
        return encode_png(flow_to_color(flow))
    return encode_flow(flow, f".{fmt}")


def confidence_job(data_a: bytes, data_b: bytes, request: MatchRequest, fmt: str) -> bytes:
    """The match's confidence map: ``.npy`` (H_a, W_a) float32 in [0, 1], or the grey PNG of
    ``reglib match --out``'s ``confidence.png`` (``round(255 * confidence)``)."""
    from reglib.io import encode_npy

    match = _match(data_a, data_b, request).match
    if match.confidence is None:
        raise InputError("the match has no confidence map: no dense stage ran (`dense` is off, the features are "
                         f"{match.features!r}, or the sparse fit gave the stage nothing to start from)")
    if fmt == "png":
        return _confidence_png(match.confidence)
    return encode_npy(np.asarray(match.confidence, dtype=np.float32))


def bundle_job(data_a: bytes, data_b: bytes, request: MatchRequest, alpha: float) -> bytes:
    """One match and every file of it: the JSON body of ``/v1/match/bundle``, encoded here.

    ``{"match": <match_job's answer>, "files": {name: base64}}``. Each file holds the bytes the
    single endpoint answers for the same request: ``warped.png`` (``/v1/warp``), ``overlay.png``
    (``/v1/warp`` with ``overlay`` and ``alpha``), ``flow.png`` and ``flow.flo`` (``/v1/flow``),
    and ``confidence.png`` (``/v1/confidence``) only when the match has a confidence map. The body
    is encoded to JSON in the worker (as ``JSONResponse`` would) so that the event loop only sends
    bytes: with base64 files it runs to tens of megabytes.
    """
    import base64
    import json

    from reglib.io import encode_flow, encode_png
    from reglib.visualize import flow_to_color
    from reglib.visualize import overlay as blend

    matched = _match(data_a, data_b, request)
    warped, flow = _warped(matched, "linear"), _flow(matched)
    files = {"warped.png": encode_png(_png_bands(warped)),
             "overlay.png": encode_png(blend(matched.image_a, warped, alpha)),
             "flow.png": encode_png(flow_to_color(flow)), "flow.flo": encode_flow(flow, ".flo")}
    if matched.match.confidence is not None:
        files["confidence.png"] = _confidence_png(matched.match.confidence)
    answer = {"match": _body(matched),
              "files": {name: base64.b64encode(blob).decode("ascii") for name, blob in files.items()}}
    return json.dumps(answer, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode("utf-8")
