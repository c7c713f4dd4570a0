"""What the point-file readers share: the :class:`PointCloud` they return, the size limit and column helpers."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._repr import short_repr
from ..errors import InputError

__all__ = ["MAX_FILE_POINTS", "PointCloud", "element_count", "points_from", "stack_columns"]

MAX_FILE_POINTS = 50_000_000


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Points read from a file, with the colours and normals it carried.

    Attributes
    ----------
    points : (N, D) float64 ndarray, or (H, W, 3) for an organized scan
        D in {2, 3}; an organized scan has NaN where the sensor saw nothing.
    colors : ndarray or None
        RGB in [0, 1], shaped like ``points`` (per point), when the file has colours.
    normals : (N, 3) float64 ndarray or None
        When the file has ``nx ny nz``.
    """

    points: np.ndarray
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None

    def __repr__(self) -> str:
        return short_repr(self, ("points", "colors", "normals"))

    @property
    def organized(self) -> bool:
        """True for an (H, W, 3) grid."""
        return self.points.ndim == 3


def element_count(text: str, file: str) -> int:
    """A header's element (or point) count, refused unless an integer in [0, MAX_FILE_POINTS]."""
    try:
        n = int(text)
    except ValueError:
        raise InputError(f"{file}: bad element count {text!r}") from None
    if n < 0 or n > MAX_FILE_POINTS:
        raise InputError(f"{file}: {n} elements; at most {MAX_FILE_POINTS} are read")
    return n


def points_from(columns: dict[str, np.ndarray]) -> np.ndarray:
    """(N, D) points: the ``x``, ``y`` and ``z`` columns that are present, in that order."""
    return np.column_stack([columns[c] for c in ("x", "y", "z") if c in columns])


def stack_columns(columns: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray | None:
    """(N, len(names)) of the named columns side by side, or None when any of them is missing."""
    if not set(names) <= set(columns):
        return None
    return np.column_stack([columns[c] for c in names])
