"""Validation at the public boundary: every public function turns its input into trusted arrays here.

Private solvers never re-check what these functions return.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

from .errors import InputError

__all__ = ["as_points", "as_point_pair", "as_options", "as_choice", "as_rng", "seed_of", "check_range", "check_int",
           "is_number", "as_colors"]

T = TypeVar("T")
S = TypeVar("S", bound=str)


MAX_COORDINATE = 1e100  # largest coordinate magnitude accepted (its square times any kernel width stays finite)


def as_points(value: Any, name: str, *, dims: tuple[int, ...] = (2, 3)) -> np.ndarray:
    """Return ``value`` as a new C-contiguous (N, D) float64 array, D in ``dims``.

    Raises
    ------
    InputError
        When ``value`` is not numeric, not two-dimensional, has a D outside ``dims``, holds NaN
        or inf, or coordinates beyond ``MAX_COORDINATE`` (1e100). The message names ``name``.
    """
    try:
        arr = np.array(value, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise InputError(
            f"`{name}` must be a numeric array of shape (N, D), got {type(value).__name__}: {exc}") from None
    shapes = " or ".join(f"(N, {d})" for d in dims)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, dims[0])
    if arr.ndim != 2 or arr.shape[1] not in dims:
        raise InputError(f"`{name}` must have shape {shapes}, got {arr.shape}")
    if not np.isfinite(arr).all():
        bad = int((~np.isfinite(arr)).any(axis=1).sum())
        raise InputError(f"`{name}` must be finite, got NaN or inf in {bad} row(s)")
    largest = float(np.abs(arr).max(initial=0.0))
    if largest > MAX_COORDINATE:
        # Squared distances of such values overflow float64 (and no coordinate system needs them).
        raise InputError(f"`{name}` has coordinates up to {largest:.3g} in magnitude; "
                         f"at most {MAX_COORDINATE:.0e} is supported")
    return np.ascontiguousarray(arr)


def as_colors(value: Any, name: str, *, rows: np.ndarray | None = None) -> np.ndarray:
    """Return RGB ``value`` as a new float64 array of its shape with values in [0, 1].

    Colours come as users hold them: uint8 channels (0-255, as images and most point-cloud tools
    keep them) are divided by 255; any other real numbers (floats, or the integers a JSON list
    gives) must already be in [0, 1]. 8-bit values in a wider integer type are refused rather
    than guessed at: 1 would mean full intensity in one convention and almost black in the other.

    Parameters
    ----------
    value : array_like
        The colours; their shape is the caller's to check.
    name : str
        The argument, for messages.
    rows : ndarray, optional
        Mask or indices over the rows of ``value`` (its last axis the channels) that must be
        finite and in range; the others (an organized scan's missing pixels) are not looked at.

    Raises
    ------
    InputError
        A dtype that is not a real number, a non-finite value, or values out of range; the
        message names ``name``, the dtype and the range of the values found.
    """
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"`{name}` must be numbers (RGB), got {type(value).__name__}: {exc}") from None
    if arr.dtype == np.uint8:
        return arr.astype(np.float64) / 255.0
    wanted = f"`{name}` must be RGB values in [0, 1] (floats) or 0-255 (uint8)"
    if arr.dtype.kind not in "iuf":
        raise InputError(f"{wanted}, got dtype {arr.dtype}")
    rgb = arr.astype(np.float64)
    looked = rgb if rows is None or rgb.ndim == 0 else rgb.reshape(-1, rgb.shape[-1])[rows]
    if not np.isfinite(looked).all():
        raise InputError(f"`{name}` must be finite" + ("" if rows is None else " where the points are"))
    if looked.size and (looked.min() < 0.0 or looked.max() > 1.0):
        raise InputError(f"{wanted}, got {arr.dtype} values in [{looked.min():g}, {looked.max():g}]")
    return rgb


def as_point_pair(src: Any, dst: Any, *, names: tuple[str, str] = ("src", "dst")) -> tuple[np.ndarray, np.ndarray]:
    """Validate two index-aligned point sets: same N and same D."""
    a = as_points(src, names[0])
    b = as_points(dst, names[1])
    if b.shape != a.shape:
        raise InputError(f"`{names[1]}` must have the same shape as `{names[0]}` {a.shape}, got {b.shape}")
    return a, b


def as_options(options: Any, cls: type[T], name: str = "options") -> T:
    """Accept None, an instance of the frozen options dataclass ``cls``, or a mapping of its fields.

    A misspelled field is an ``InputError`` that lists the valid ones; a field that ``cls`` lists in
    its ``RENAMED_FIELDS`` class attribute (old name -> new name) is an ``InputError`` naming the new one.
    """
    if options is None:
        return cls()
    if isinstance(options, cls):
        return options
    if isinstance(options, Mapping):
        fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]  # cls: a dataclass, by contract
        renamed: Mapping[str, str] = getattr(cls, "RENAMED_FIELDS", {})
        old = sorted(set(options) & set(renamed))
        if old:
            raise InputError(f"`{name}` field `{old[0]}` was renamed to `{renamed[old[0]]}`")
        unknown = sorted(set(options) - fields)
        if unknown:
            raise InputError(f"`{name}` has unknown field(s) {unknown}; valid fields are {sorted(fields)}")
        try:
            return cls(**options)
        except (TypeError, ValueError) as exc:
            raise InputError(f"`{name}`: {exc}") from None
    raise InputError(f"`{name}` must be None, a {cls.__name__} or a dict, got {type(options).__name__}")


def as_choice(value: Any, name: str, choices: tuple[S, ...]) -> S:
    """Return ``value`` if it is one of ``choices``, else an ``InputError`` listing them.

    The result has the type of ``choices``' items: a tuple of ``Literal`` strings gives that ``Literal``.
    """
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"`{name}` must be one of {list(choices)}, got {value!r}")
    return value  # checked above: one of ``choices`` (mypy narrows it to S)


def as_rng(rng: Any) -> np.random.Generator:
    """``np.random.default_rng(rng)`` with a named error for values it refuses."""
    try:
        return np.random.default_rng(rng)
    except (TypeError, ValueError) as exc:
        raise InputError(f"`rng` must be None, an int seed or a numpy Generator, got {rng!r}: {exc}") from None


def seed_of(rng: Any) -> int | None:
    """The integer seed that ``rng`` is, recorded in results for reproduction; None for a Generator or None."""
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return int(rng)
    return None


def check_range(name: str, value: float, low: float | None = None, high: float | None = None,
                *, low_open: bool = False, high_open: bool = False) -> None:
    """Raise ``InputError`` (via ValueError inside dataclass ``__post_init__``) when out of range."""
    numeric = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not numeric or not np.isfinite(value):
        raise InputError(f"`{name}` must be a finite number, got {value!r}")
    if low is not None and (value <= low if low_open else value < low):
        raise InputError(f"`{name}` must be {'>' if low_open else '>='} {low}, got {value!r}")
    if high is not None and (value >= high if high_open else value > high):
        raise InputError(f"`{name}` must be {'<' if high_open else '<='} {high}, got {value!r}")


def check_int(name: str, value: Any, low: int = 1, high: int | None = None) -> int:
    """Return ``value`` as an int if it is an integer (not a bool) in [``low``, ``high``], else an ``InputError``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        what = {0: "a non-negative integer", 1: "a positive integer"}.get(low, f"an integer >= {low}")
        raise InputError(f"`{name}` must be {what}, got {value!r}")
    if high is not None and value > high:
        raise InputError(f"`{name}` must be <= {high}, got {value!r}")
    return int(value)


def is_number(word: str) -> bool:
    """Whether the text ``word`` reads as a number (``float(word)`` succeeds)."""
    try:
        float(word)
    except ValueError:
        return False
    return True
