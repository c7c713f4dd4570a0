"""Reading the library's own JSON forms back: field checks shared by the results' ``from_dict``.

Every helper raises ``InputError`` naming the field (``what`` names the form, e.g. "filter result").
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from ._verdict import REASONS, Reason
from .errors import InputError

__all__ = ["require_fields", "as_array", "as_index_mask", "as_matches", "as_int", "as_float", "as_bool", "as_reason",
           "as_seed"]


def require_fields(data: Any, keys: tuple[str, ...], what: str) -> Mapping[str, Any]:
    """``data`` as a mapping holding every one of ``keys``."""
    if not isinstance(data, Mapping):
        raise InputError(f"a {what} must be a JSON object, got {type(data).__name__}")
    missing = [k for k in keys if k not in data]
    if missing:
        raise InputError(f"the {what} is missing field(s) {missing}")
    return data


def as_array(value: Any, key: str, what: str, *, shape: tuple[int | None, ...], dtype: Any = np.float64) -> np.ndarray:
    """A finite array of ``shape`` (None: any length) from nested lists."""
    try:
        arr = np.array(value, dtype=dtype)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{what} `{key}` must be numbers (nested lists), got {type(value).__name__}") from None
    if arr.size == 0 and len(shape) > 1 and arr.ndim < len(shape):
        arr = arr.reshape((0,) + tuple(s or 0 for s in shape[1:]))
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"{what} `{key}` must have shape {want}, got {arr.shape}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise InputError(f"{what} `{key}` must hold only finite numbers")
    return arr


def as_index_mask(value: Any, n: int, key: str, what: str) -> np.ndarray:
    """An (n,) bool mask from a list of distinct indices in [0, n)."""
    idx = as_array(value, key, what, shape=(None,), dtype=np.float64)
    if not np.all(idx == np.round(idx)) or (len(idx) and (idx.min() < 0 or idx.max() >= n)):
        raise InputError(f"{what} `{key}` must be integer indices in [0, {n}), got {value!r:.80}")
    mask = np.zeros(n, dtype=bool)
    mask[idx.astype(np.intp)] = True
    if int(mask.sum()) != len(idx):
        raise InputError(f"{what} `{key}` holds repeated indices")
    return mask


def as_int(value: Any, key: str, what: str, *, low: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InputError(f"{what} `{key}` must be an integer >= {low}, got {value!r}")
    return value


def as_float(value: Any, key: str, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{what} `{key}` must be a finite number, got {value!r}")
    return float(value)


def as_bool(value: Any, key: str, what: str) -> bool:
    if not isinstance(value, bool):
        raise InputError(f"{what} `{key}` must be true or false, got {value!r}")
    return value


def as_reason(value: Any, key: str, what: str) -> Reason | None:
    """``value`` as a reason code (:data:`reglib._verdict.REASONS`) or None."""
    if value is None:
        return None
    if not isinstance(value, str):
        raise InputError(f"{what} `{key}` must be null or a string, got {value!r}")
    if value in REASONS:
        return cast(Reason, value)  # checked above: one of the codes
    raise InputError(f"{what} `{key}` must be null or one of {', '.join(REASONS)}, got {value!r}")


def as_seed(value: Any, key: str, what: str) -> int | None:
    if value is None:
        return None
    return as_int(value, key, what)


def as_matches(d: Mapping[str, Any], what: str) -> tuple[int, np.ndarray, np.ndarray]:
    """``n_matches``, ``inliers`` (as an (N,) mask, agreeing with ``n_inliers``) and ``scores`` (N,)."""
    n = as_int(d["n_matches"], "n_matches", what)
    # the scores' length first: a claimed n_matches is checked against data before a mask of n is made
    scores = as_array(d["scores"], "scores", what, shape=(None,))
    if len(scores) != n:
        raise InputError(f"{what} `scores` must have shape ({n},) (one per match), got {scores.shape}")
    inliers = as_index_mask(d["inliers"], n, "inliers", what)
    if as_int(d["n_inliers"], "n_inliers", what) != int(inliers.sum()):
        raise InputError(f"{what} `n_inliers` {d['n_inliers']} disagrees with `inliers` ({int(inliers.sum())})")
    return n, inliers, scores
