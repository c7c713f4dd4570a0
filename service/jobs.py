"""What the workers run: plain functions of plain arguments, returning JSON-ready dicts or bytes.

These run in the pool's processes (see :mod:`service.pool`); they import reglib lazily, validate
through the library's own public functions, and never touch the web framework. Each answer is the
library's answer for the same inputs and seed, in the JSON forms of CONTRACTS.md.
"""
from __future__ import annotations

import io
import struct
import time
from typing import Any, Literal

import numpy as np

from reglib.errors import ImageTooLarge, InputError, UnsupportedFormat

from .pool import UndecodableImage

__all__ = ["filter_job", "register_job", "match_job", "warp_job", "flow_job", "filter_body", "register_body"]


def filter_body(result: Any, seed: int) -> dict[str, Any]:
    """The JSON answer of ``/v1/filter`` for a :class:`reglib.FilterResult`."""
    return {"n_matches": int(len(result.inliers)), "n_inliers": int(result.n_inliers),
            "inliers": np.flatnonzero(result.inliers).tolist(), "scores": np.asarray(result.scores).tolist(),
            "transform": result.transform.to_dict(), "converged": bool(result.converged), "reason": result.reason,
            "sigma": float(result.sigma), "n_iter": int(result.n_iter), "seed": seed}


def register_body(model: np.ndarray, registration: Any, seed: int) -> dict[str, Any]:
    """The JSON answer of ``/v1/register`` for a :class:`reglib.Registration` of ``model``."""
    return {"registered": np.asarray(registration.transform(model), dtype=np.float64).tolist(),
            "correspondence": np.asarray(registration.correspondence).astype(int).tolist(),
            "transform": registration.transform.to_dict(), "converged": bool(registration.converged),
            "n_iter": int(registration.n_iter), "seed": seed}


def filter_job(src: list[Any], dst: list[Any], method: Literal["l2e", "vfc"], options: dict[str, Any] | None,
               seed: int) -> dict[str, Any]:
    from reglib import filter_matches

    start = time.perf_counter()
    result = filter_matches(src, dst, method=method, options=options, rng=seed)
    body = filter_body(result, seed)
    body["timings_ms"] = {"filter": (time.perf_counter() - start) * 1e3}
    return body


def register_job(model: list[Any], target: list[Any], method: Literal["l2e", "cpd", "cpd-rigid", "cpd-affine"],
                 options: dict[str, Any] | None, seed: int) -> dict[str, Any]:
    from reglib import register_points
    from reglib._validation import as_points

    model_a = as_points(model, "model")
    registration = register_points(model_a, target, method=method, options=options, rng=seed)
    return register_body(model_a, registration, seed)


def _decode(data: bytes, max_pixels: int, name: str) -> np.ndarray:
    from reglib.io import read_image

    try:
        return read_image(data, max_pixels=max_pixels, name=name)
    except (ImageTooLarge, UnsupportedFormat):
        raise
    except InputError as exc:
        raise UndecodableImage(str(exc)) from None


def _match(data_a: bytes, data_b: bytes, options: dict[str, Any], max_pixels: int) -> tuple[Any, Any, Any, dict]:
    start = time.perf_counter()
    image_a = _decode(data_a, max_pixels, "image_a")
    image_b = _decode(data_b, max_pixels, "image_b")
    decode_ms = (time.perf_counter() - start) * 1e3
    from reglib import match_images
    opts = dict(options)
    seed = opts.pop("seed")
    features = opts.pop("features", "sift")
    method = opts.pop("method", "l2e")
    opts.setdefault("max_pixels", max_pixels)
    match = match_images(image_a, image_b, features=features, method=method, options=opts, rng=seed)
    return image_a, image_b, match, {"decode": decode_ms}


def match_job(data_a: bytes, data_b: bytes, options: dict[str, Any], max_pixels: int) -> dict[str, Any]:
    _, _, match, timings = _match(data_a, data_b, options, max_pixels)
    body = match.to_dict()
    body["seed"] = options["seed"]
    body["timings_ms"] = {**timings, **body.get("timings_ms", {})}
    return body


def warp_job(data_a: bytes, data_b: bytes, options: dict[str, Any], max_pixels: int, overlay: bool,
             alpha: float, interpolation: Literal["linear", "nearest"]) -> bytes:
    from reglib import warp_image
    from reglib.io import encode_png
    from reglib.visualize import overlay as blend

    image_a, image_b, match, _ = _match(data_a, data_b, options, max_pixels)
    warped, _valid = warp_image(image_b, match.transform, image_a.shape[:2], interpolation=interpolation)
    return encode_png(blend(image_a, warped, alpha) if overlay else warped)


def flow_job(data_a: bytes, data_b: bytes, options: dict[str, Any], max_pixels: int, fmt: str) -> bytes:
    from reglib import dense_flow
    from reglib.io import encode_png
    from reglib.visualize import flow_to_color

    image_a, _, match, _ = _match(data_a, data_b, options, max_pixels)
    flow = np.asarray(dense_flow(match.transform, image_a.shape[:2]), dtype=np.float32)
    if fmt == "png":
        return encode_png(flow_to_color(flow))
    if fmt == "flo":
        return encode_flo(flow)
    buffer = io.BytesIO()
    np.save(buffer, flow, allow_pickle=False)
    return buffer.getvalue()


def encode_flo(flow: np.ndarray) -> bytes:
    """Middlebury .flo bytes: b"PIEH", int32 width, int32 height, then (H, W, 2) float32 little-endian."""
    h, w = flow.shape[:2]
    return b"PIEH" + struct.pack("<ii", w, h) + np.ascontiguousarray(flow, dtype="<f4").tobytes()
