"""Writing point sets: :func:`write_points` (points, with colours and normals where the format holds them)
and :func:`write_point_cloud` (a :class:`~reglib.io.PointCloud` as :func:`~reglib.io.read_point_cloud`
returns it).

Coordinates and normals are written as ``repr`` of float64 (doubles in PLY and PCD), so reading a
file back gives the same numbers; colours as 8-bit channels, the form PLY and PCD tools expect.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import as_colors
from ..errors import InputError
from ._cloud import PointCloud
from ._files import write_bytes_atomic
from ._flow import encode_npy

__all__ = ["write_point_cloud", "write_points"]

_WITH_FIELDS = (".ply", ".pcd")  # the formats that hold colours and normals beside the points


def write_points(path: str | os.PathLike[str], points: Any, *, colors: Any = None, normals: Any = None) -> None:
    """Write (N, D) points by suffix: ``.npy``, ``.ply`` (ascii, doubles), ``.pcd`` (ascii), else text.

    Parameters
    ----------
    path : str or os.PathLike
        The file; written atomically.
    points : (N, 2) or (N, 3) array_like
        x, y[, z]; 2-D points get z = 0 in PLY and PCD files.
    colors : (N, 3) array_like, optional
        RGB as uint8 (0-255) or as numbers in [0, 1]; written as 8-bit channels (a float is
        rounded to the nearest of 256 levels), so uint8 colours read back exactly
        (``round(255 * read_point_cloud(path).colors)``). PLY and PCD only.
    normals : (N, D) array_like, optional
        Normals, one per point (2-D ones get a zero z), written as doubles (``nx ny nz`` in PLY,
        ``normal_x normal_y normal_z`` in PCD). PLY and PCD only.

    Raises
    ------
    InputError
        Points that are not (N, 2) or (N, 3) numbers; colours of another shape, a dtype other
        than uint8 or real numbers, or values outside [0, 1] (the message names the dtype and
        the range found); normals of another shape or not finite; colours or normals for a
        text or ``.npy`` file, which holds the points alone.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from reglib.io import read_point_cloud
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "p.ply"
    >>> rgb = np.array([[255, 128, 0], [7, 8, 9]], dtype=np.uint8)
    >>> write_points(path, np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]), colors=rgb)
    >>> np.round(read_point_cloud(path).colors * 255).astype(np.uint8)
    array([[255, 128,   0],
           [  7,   8,   9]], dtype=uint8)
    """
    p = Path(path)
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"`points` must be numbers of shape (N, 2) or (N, 3), got {type(points).__name__}") from None
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise InputError(f"`points` must have shape (N, 2) or (N, 3), got {pts.shape}")
    rgb = None if colors is None else _channels(colors, len(pts))
    nrm = None if normals is None else _normals(normals, pts.shape)
    suffix = p.suffix.lower()
    if (rgb is not None or nrm is not None) and suffix not in _WITH_FIELDS:
        given = " and ".join(k for k, v in (("`colors`", rgb), ("`normals`", nrm)) if v is not None)
        raise InputError(f"{p.name}: a {suffix or 'text'} file holds the points alone; {given} go into "
                         f"{' or '.join(_WITH_FIELDS)} files")
    if suffix == ".npy":
        write_bytes_atomic(p, encode_npy(pts))
        return
    if suffix not in _WITH_FIELDS:
        write_bytes_atomic(p, _text([_numbers(pts)], []).encode())
        return
    xyz = _padded(pts)
    numbers = [_numbers(xyz)] + ([] if nrm is None else [_numbers(_padded(nrm))])
    if suffix == ".ply":
        body = _text(numbers + ([] if rgb is None else [_integers(rgb)]), _ply_header(len(xyz), rgb, nrm))
    else:
        packed = None if rgb is None else (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
        body = _text(numbers + ([] if packed is None else [_integers(packed[:, None])]),
                     _pcd_header(len(xyz), rgb, nrm))
    write_bytes_atomic(p, body.encode())


def write_point_cloud(path: str | os.PathLike[str], cloud: PointCloud) -> None:
    """Write a :class:`~reglib.io.PointCloud` by suffix, with what the format holds.

    PLY and PCD files get the points with the cloud's colours and normals (:func:`write_points`);
    text and ``.npy`` files the points alone. An organized (H, W, 3) cloud is written as its
    points that were seen (the rows without NaN), in row-major order.

    Raises
    ------
    InputError
        What :func:`write_points` refuses, or a value that is not a PointCloud.
    """
    if not isinstance(cloud, PointCloud):
        raise InputError(f"`cloud` must be a reglib.io.PointCloud, got {type(cloud).__name__}")
    pts = np.asarray(cloud.points, dtype=np.float64)
    width = pts.shape[-1] if pts.ndim else 0
    rows = pts.reshape(-1, width) if cloud.organized else pts
    seen = np.isfinite(rows).all(axis=1) if cloud.organized else slice(None)
    fields = Path(path).suffix.lower() in _WITH_FIELDS

    def kept(values: np.ndarray | None, channels: int) -> np.ndarray | None:
        if values is None or not fields:
            return None
        arr = np.asarray(values)
        return arr.reshape(-1, channels)[seen] if cloud.organized else arr

    write_points(path, rows[seen], colors=kept(cloud.colors, 3), normals=kept(cloud.normals, width))


def _channels(colors: Any, n: int) -> np.ndarray:
    """(n, 3) int64 8-bit channels of colours given as uint8 or as numbers in [0, 1]."""
    rgb = as_colors(colors, "colors")
    if rgb.shape != (n, 3):
        raise InputError(f"`colors` must have shape {(n, 3)}, got {rgb.shape}")
    return np.round(rgb * 255.0).astype(np.int64)


def _normals(normals: Any, shape: tuple[int, ...]) -> np.ndarray:
    """(N, D) finite float64 normals, one per point."""
    try:
        nrm = np.asarray(normals, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"`normals` must be numbers of shape {shape}") from None
    if nrm.shape != shape:
        raise InputError(f"`normals` must have the shape of the points, {shape}, got {nrm.shape}")
    if not np.isfinite(nrm).all():
        raise InputError("`normals` must be finite")
    return nrm


def _padded(rows: np.ndarray) -> np.ndarray:
    """(N, 3): 2-D rows with a zero third column."""
    return rows if rows.shape[1] == 3 else np.c_[rows, np.zeros(len(rows))]


def _numbers(table: np.ndarray) -> list[str]:
    return [" ".join(repr(float(v)) for v in row) for row in table]


def _integers(table: np.ndarray) -> list[str]:
    return [" ".join(str(int(v)) for v in row) for row in table]


def _text(columns: list[list[str]], header: list[str]) -> str:
    """The header lines, then one line per point: the column blocks side by side."""
    rows = [" ".join(parts) for parts in zip(*columns, strict=True)] if columns else []
    return "\n".join(header + rows) + "\n"


def _ply_header(n: int, rgb: np.ndarray | None, nrm: np.ndarray | None) -> list[str]:
    props = ["x", "y", "z"] + ([] if nrm is None else ["nx", "ny", "nz"])
    colour = [] if rgb is None else [f"property uchar {c}" for c in ("red", "green", "blue")]
    return (["ply", "format ascii 1.0", f"element vertex {n}"] + [f"property double {c}" for c in props]
            + colour + ["end_header"])


def _pcd_header(n: int, rgb: np.ndarray | None, nrm: np.ndarray | None) -> list[str]:
    fields = ["x", "y", "z"] + ([] if nrm is None else ["normal_x", "normal_y", "normal_z"])
    sizes, types = ["8"] * len(fields), ["F"] * len(fields)
    if rgb is not None:  # packed 0x00RRGGBB as an unsigned integer
        fields, sizes, types = fields + ["rgb"], sizes + ["4"], types + ["U"]
    return ["# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7", f"FIELDS {' '.join(fields)}",
            f"SIZE {' '.join(sizes)}", f"TYPE {' '.join(types)}", f"COUNT {' '.join(['1'] * len(fields))}",
            f"WIDTH {n}", "HEIGHT 1", "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {n}", "DATA ascii"]
