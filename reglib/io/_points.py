"""Point-set files: whitespace / CSV text, ``.npy``, PLY and PCD (ASCII and binary), without Open3D.

:func:`read_point_cloud` returns the points with whatever colours and normals the file has;
an organized PCD (``HEIGHT`` > 1, as depth cameras write) keeps its (H, W, 3) grid with NaN where
nothing was seen. :func:`read_points` returns the points alone; :func:`write_points` and :func:`write_point_cloud`
(:mod:`reglib.io._write_points`) write by suffix.
Sizes are read from the header and checked against the file before anything is allocated.
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .._validation import is_number
from ..errors import InputError
from ._cloud import MAX_FILE_POINTS as MAX_FILE_POINTS  # re-exported: the point limit every reader applies
from ._cloud import PointCloud
from ._pcd import read_pcd
from ._ply import read_ply
from ._write_points import write_point_cloud, write_points

__all__ = ["PointCloud", "read_point_cloud", "read_points", "write_points", "write_point_cloud", "read_matches",
           "POINT_SUFFIXES"]

POINT_SUFFIXES = (".txt", ".xyz", ".csv", ".npy", ".ply", ".pcd")


def read_points(path: str | os.PathLike[str]) -> np.ndarray:
    """The points of a point-set file (see :func:`read_point_cloud`), colours and normals dropped."""
    return read_point_cloud(path).points


def read_point_cloud(path: str | os.PathLike[str]) -> PointCloud:
    """Read a point set from text (``.txt``, ``.xyz``, ``.csv``: one point a row), ``.npy``, ``.ply`` or ``.pcd``.

    Text and ``.npy`` hold (N, 2) or (N, 3) numbers (an (H, W, 3) ``.npy`` is an organized scan; in
    text, a first row of non-numbers such as ``x,y,z`` is a header and skipped);
    PLY (ascii, binary little or big endian) reads the ``vertex`` element's x, y[, z], optional
    red / green / blue and nx / ny / nz; PCD (ascii or binary; ``binary_compressed`` is refused
    by name) reads x, y[, z], ``rgb`` / ``rgba`` (packed) and normal_x / y / z, organized when
    ``HEIGHT`` > 1.

    Raises
    ------
    InputError
        A missing file, an unknown suffix, a malformed header, a size that disagrees with the
        file, or more than 50,000,000 points.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> write_points(folder / "p.ply", np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]))
    >>> read_points(folder / "p.ply")
    array([[0., 1., 2.],
           [3., 4., 5.]])
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"no such point file: {p}")
    suffix = p.suffix.lower()
    if suffix == ".npy":
        try:
            arr = np.load(p, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise InputError(f"{p.name}: not a numeric .npy array: {exc}") from None
        if arr.dtype.kind not in "iuf" or not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
            raise InputError(f"{p.name}: expected a numeric (N, D) or (H, W, 3) array, got {arr.dtype} {arr.shape}")
        return PointCloud(points=np.asarray(arr, dtype=np.float64))
    if suffix == ".ply":
        return read_ply(p)
    if suffix == ".pcd":
        return read_pcd(p)
    if suffix in (".txt", ".xyz", ".csv", ""):
        return PointCloud(points=_read_table(p, "table of points"))
    raise InputError(f"{p.name}: unknown point file suffix {suffix!r}; use one of {list(POINT_SUFFIXES)}")


def read_matches(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Putative matches (src, dst) from a file; row i of ``src`` is matched to row i of ``dst``.

    An ``.npz`` holds arrays ``src`` and ``dst``, each (N, 2) or (N, 3) of (x, y[, z]). A text
    table (whitespace-separated, or commas for ``.csv``; ``#`` starts a comment) has rows
    ``x_a y_a x_b y_b`` (2-D, 4 columns) or ``x_a y_a z_a x_b y_b z_b`` (3-D, 6 columns), x the
    column in images; a first row of non-numbers (e.g. ``x_a,y_a,x_b,y_b``) is a header and skipped.

    Raises
    ------
    InputError
        A missing file, an ``.npz`` without ``src`` and ``dst`` (the message lists the arrays it
        holds), a table that is not numeric or has another number of columns.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"no such matches file: {p}")
    if p.suffix.lower() == ".npz":
        try:
            with np.load(p, allow_pickle=False) as data:
                keys = sorted(data.files)
                arrays = {k: np.asarray(data[k]) for k in ("src", "dst") if k in keys}
        except (ValueError, OSError) as exc:
            raise InputError(f"{p.name}: not a readable .npz file: {exc}") from None
        if len(arrays) != 2:
            raise InputError(f"{p.name}: an .npz of matches needs arrays `src` and `dst` ((N, 2) or (N, 3) each, "
                             f"row i of src matched to row i of dst); it holds {keys}")
        return arrays["src"], arrays["dst"]
    table = _read_table(p, "table")
    if table.shape[1] not in (4, 6):
        raise InputError(f"{p.name}: expected 4 (2-D) or 6 (3-D) columns, got {table.shape[1]}")
    half = table.shape[1] // 2
    return table[:, :half], table[:, half:]


def _header_rows(p: Path, delimiter: str | None) -> int:
    """How many lines to skip so that a first row of non-numbers (a header such as ``x,y``) is left out: 0 if none.

    Only the file's first lines are read; blank and ``#`` comment lines before the header count too.
    """
    with p.open("r", encoding="utf-8", errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            text = line.split("#", 1)[0].strip()
            if not text:
                if number > 1000:  # no rows in the first 1000 lines: np.loadtxt says what is wrong
                    return 0
                continue
            words = [w.strip() for w in text.split(delimiter)]
            return number if all(w and not is_number(w) for w in words) else 0
    return 0


def _read_table(p: Path, what: str) -> np.ndarray:
    """(N, K) float64 rows of a text file (whitespace-separated, commas for ``.csv``, ``#`` comments), N >= 1.

    A first row of non-numbers is a header and skipped.
    """
    delimiter = "," if p.suffix.lower() == ".csv" else None
    skip = _header_rows(p, delimiter)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # numpy's "input contained no data": said below
        try:
            table = np.loadtxt(p, ndmin=2, delimiter=delimiter, comments="#", skiprows=skip)
        except ValueError as exc:
            raise InputError(f"{p.name}: not a numeric {what}: {exc}") from None
    if table.size == 0:
        raise InputError(f"{p.name}: no rows of numbers in the file" + (" (only a header)" if skip else ""))
    return table
