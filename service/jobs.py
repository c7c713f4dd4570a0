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

__all__ = ["filter_job", "register_job", "match_job", "warp_job", "flow_job", "confidence_job"]


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
        result = register_points(_points(model, "model"), _points(target, "target"),  # type: ignore[arg-type]
                                 method=method, options=options, rng=seed, **extra)
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


def match_job(data_a: bytes, data_b: bytes, request: MatchRequest) -> dict[str, Any]:
    """``request.run(a, b).to_dict()``; the decode time joins ``timings_ms``."""
    matched = _match(data_a, data_b, request)
    body = matched.match.to_dict()
    body["timings_ms"] = {"decode": matched.decode_ms, **body.get("timings_ms", {})}
    return body


def warp_job(data_a: bytes, data_b: bytes, request: MatchRequest, overlay: bool, alpha: float,
             interpolation: Literal["linear", "nearest"]) -> bytes:
    """PNG of b warped onto a by the match's transform, or blended over a (weight ``alpha``) with ``overlay``."""
    from reglib import warp_image
    from reglib.io import encode_png
    from reglib.visualize import overlay as blend

    matched = _match(data_a, data_b, request)
    image_a = matched.image_a
    warped, _valid = warp_image(matched.image_b, matched.match.transform, image_a.shape[:2],
                                interpolation=interpolation)
    return encode_png(blend(image_a, warped, alpha) if overlay else warped)


def flow_job(data_a: bytes, data_b: bytes, request: MatchRequest, fmt: str) -> bytes:
    """The match's dense forward flow (H_a, W_a, 2) float32 of (dx, dy) as ``.npy``, ``.flo`` or its colour PNG."""
    from reglib import dense_flow
    from reglib.io import encode_flo, encode_npy, encode_png
    from reglib.visualize import flow_to_color

    matched = _match(data_a, data_b, request)
    flow = np.asarray(dense_flow(matched.match.transform, matched.image_a.shape[:2]), dtype=np.float32)
    if fmt == "png":
        return encode_png(flow_to_color(flow))
    if fmt == "flo":
        return encode_flo(flow)
    return encode_npy(flow)


def confidence_job(data_a: bytes, data_b: bytes, request: MatchRequest, fmt: str) -> bytes:
    """The match's confidence map: ``.npy`` (H_a, W_a) float32 in [0, 1], or the grey PNG of
    ``reglib match --out``'s ``confidence.png`` (``round(255 * confidence)``)."""
    from reglib.io import encode_npy, encode_png

    match = _match(data_a, data_b, request).match
    if match.confidence is None:
        raise InputError(f"features={match.features!r} gives no confidence map (it has no dense image support)")
    conf = np.asarray(match.confidence, dtype=np.float32)
    if fmt == "png":
        return encode_png(np.round(np.clip(conf, 0.0, 1.0) * 255.0).astype(np.uint8))
    return encode_npy(conf)
