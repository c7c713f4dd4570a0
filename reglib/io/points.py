"""Point-set files: whitespace / CSV text, ``.npy``, PLY and PCD (ASCII and binary), without Open3D.

:func:`read_point_cloud` returns the points with whatever colours and normals the file has;
an organized PCD (``HEIGHT`` > 1, as depth cameras write) keeps its (H, W, 3) grid with NaN where
nothing was seen. :func:`read_points` returns the points alone; :func:`write_points` writes by suffix.
Sizes are read from the header and checked against the file before anything is allocated.
"""
from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import is_number
from ..errors import InputError
from .files import write_bytes_atomic
from .flow import encode_npy

__all__ = ["PointCloud", "read_point_cloud", "read_points", "write_points", "read_matches", "POINT_SUFFIXES"]

POINT_SUFFIXES = (".txt", ".xyz", ".csv", ".npy", ".ply", ".pcd")
MAX_FILE_POINTS = 50_000_000

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


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

    @property
    def organized(self) -> bool:
        """True for an (H, W, 3) grid."""
        return self.points.ndim == 3


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
        return _read_ply(p)
    if suffix == ".pcd":
        return _read_pcd(p)
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


def write_points(path: str | os.PathLike[str], points: Any, *, colors: Any = None) -> None:
    """Write (N, D) points by suffix: ``.npy``, ``.ply`` (ascii, doubles), ``.pcd`` (ascii), else text.

    ``colors`` (N, 3) in [0, 1] go into PLY and PCD files. Written atomically.
    """
    p = Path(path)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise InputError(f"`points` must have shape (N, 2) or (N, 3), got {pts.shape}")
    rgb = None
    if colors is not None:
        rgb = np.asarray(colors, dtype=np.float64)
        if rgb.shape != (len(pts), 3):
            raise InputError(f"`colors` must have shape {(len(pts), 3)}, got {rgb.shape}")
        rgb = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.int64)
    suffix = p.suffix.lower()
    if suffix == ".npy":
        write_bytes_atomic(p, encode_npy(pts))
        return
    xyz = pts if pts.shape[1] == 3 else np.c_[pts, np.zeros(len(pts))]
    if suffix == ".ply":
        header = ["ply", "format ascii 1.0", f"element vertex {len(xyz)}", "property double x", "property double y",
                  "property double z"]
        if rgb is not None:
            header += ["property uchar red", "property uchar green", "property uchar blue"]
        rows = _rows(xyz, rgb, packed=False)
        write_bytes_atomic(p, ("\n".join(header + ["end_header"] + rows) + "\n").encode())
    elif suffix == ".pcd":
        fields = "x y z" + (" rgb" if rgb is not None else "")
        n_fields = 4 if rgb is not None else 3
        header = ["# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7", f"FIELDS {fields}",
                  "SIZE " + " ".join(["8"] * 3 + (["4"] if rgb is not None else [])),
                  "TYPE " + " ".join(["F"] * 3 + (["U"] if rgb is not None else [])),
                  "COUNT " + " ".join(["1"] * n_fields), f"WIDTH {len(xyz)}", "HEIGHT 1",
                  "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {len(xyz)}", "DATA ascii"]
        write_bytes_atomic(p, ("\n".join(header + _rows(xyz, rgb, packed=True)) + "\n").encode())
    else:
        write_bytes_atomic(p, ("\n".join(" ".join(repr(float(v)) for v in row) for row in pts) + "\n").encode())


def _rows(xyz: np.ndarray, rgb: np.ndarray | None, *, packed: bool) -> list[str]:
    coords = [" ".join(repr(float(v)) for v in row) for row in xyz]
    if rgb is None:
        return coords
    if packed:
        values = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
        return [f"{c} {int(v)}" for c, v in zip(coords, values, strict=True)]
    return [f"{c} {int(r)} {int(g)} {int(b)}" for c, (r, g, b) in zip(coords, rgb, strict=True)]


# ---------------------------------------------------------------------------------------- PLY
def _read_ply(p: Path) -> PointCloud:
    data = p.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputError(f"{p.name}: not a PLY file (no 'ply' magic or no end_header)")
    body_start = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]], bool]] = []
    for line in header[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            elements.append((words[1], _count(words[2], p.name), [], False))
        elif words[0] == "property" and elements:
            name, count, props, has_list = elements[-1]
            if words[1] == "list":
                elements[-1] = (name, count, props, True)
            elif words[1] in _PLY_TYPES and len(words) == 3:
                props.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise InputError(f"{p.name}: unknown PLY property line {line!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"{p.name}: unknown PLY format {fmt!r}")
    vertex = next((e for e in elements if e[0] == "vertex"), None)
    if vertex is None or not {"x", "y"} <= {n for n, _ in vertex[2]}:
        raise InputError(f"{p.name}: PLY header needs a vertex element with x and y properties")
    _, n, props, has_list = vertex
    if has_list:
        raise InputError(f"{p.name}: list properties in the PLY vertex element are not supported")
    before = elements[:elements.index(vertex)]
    if fmt == "ascii":
        lines = data[body_start:].decode("ascii", errors="replace").split("\n")
        skip = sum(e[1] for e in before)
        rows = [ln for ln in lines[skip:skip + n]]
        try:
            table = np.array([r.split()[:len(props)] for r in rows], dtype=np.float64)
        except ValueError as exc:
            raise InputError(f"{p.name}: malformed PLY vertex data: {exc}") from None
        if table.shape != (n, len(props)):
            raise InputError(f"{p.name}: the header says {n} vertices of {len(props)} values, the data differ")
        columns = {name: table[:, k] for k, (name, _) in enumerate(props)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        offset = body_start
        for name, count, eprops, elist in before:
            if elist:
                raise InputError(f"{p.name}: element {name!r} with list properties before the vertices "
                                 "is not supported")
            offset += count * sum(np.dtype(t).itemsize for _, t in eprops)
        dtype = np.dtype([(name, order + t) for name, t in props])
        if offset + n * dtype.itemsize > len(data):
            raise InputError(f"{p.name}: the header says {n} vertices ({n * dtype.itemsize} bytes); "
                             "the file is shorter")
        rec = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
        columns = {name: rec[name].astype(np.float64) for name, _ in props}
    names = [c for c in ("x", "y", "z") if c in columns]
    points = np.column_stack([columns[c] for c in names])
    colors = None
    if {"red", "green", "blue"} <= set(columns):
        colors = np.column_stack([columns[c] for c in ("red", "green", "blue")])
        kinds = dict(props)
        colors = colors / (255.0 if kinds["red"] in ("u1", "i1") or colors.max(initial=0) > 1 else 1.0)
    normals = None
    if {"nx", "ny", "nz"} <= set(columns):
        normals = np.column_stack([columns[c] for c in ("nx", "ny", "nz")])
    return PointCloud(points=points, colors=colors, normals=normals)


def _count(text: str, file: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise InputError(f"{file}: bad element count {text!r}") from None
    if n < 0 or n > MAX_FILE_POINTS:
        raise InputError(f"{file}: {n} elements; at most {MAX_FILE_POINTS} are read")
    return n


# ---------------------------------------------------------------------------------------- PCD
def _read_pcd(p: Path) -> PointCloud:
    data = p.read_bytes()
    head: dict[str, list[str]] = {}
    pos = 0
    while True:
        nl = data.find(b"\n", pos)
        if nl < 0:
            raise InputError(f"{p.name}: not a PCD file (no DATA line)")
        line = data[pos:nl].decode("ascii", errors="replace").strip()
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        words = line.split()
        head[words[0].upper()] = words[1:]
        if words[0].upper() == "DATA":
            break
    try:
        fields = head["FIELDS"]
        sizes = [int(v) for v in head["SIZE"]]
        types = head["TYPE"]
        counts = [int(v) for v in head.get("COUNT", ["1"] * len(fields))]
        width, height = _count(head["WIDTH"][0], p.name), _count(head.get("HEIGHT", ["1"])[0], p.name)
        mode = head["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as exc:
        raise InputError(f"{p.name}: malformed PCD header ({exc})") from None
    if not (len(fields) == len(sizes) == len(types) == len(counts)) or "x" not in fields or "y" not in fields:
        raise InputError(f"{p.name}: PCD header needs FIELDS with x and y and matching SIZE / TYPE / COUNT")
    n = width * height
    if n > MAX_FILE_POINTS:
        raise InputError(f"{p.name}: {n} points; at most {MAX_FILE_POINTS} are read")
    kinds = {"F": "f", "U": "u", "I": "i"}
    try:
        parts = [(f, kinds[t.upper()] + str(s), c) for f, s, t, c in zip(fields, sizes, types, counts, strict=True)]
    except KeyError:
        raise InputError(f"{p.name}: unknown PCD TYPE in {types}") from None
    if mode == "ascii":
        text = data[pos:].decode("ascii", errors="replace").split()
        width_values = sum(c for _, _, c in parts)
        if len(text) < n * width_values:
            raise InputError(f"{p.name}: the header says {n} points of {width_values} values; the data are shorter")
        table = np.array(text[:n * width_values], dtype=np.float64).reshape(n, width_values)
        columns: dict[str, np.ndarray] = {}
        k = 0
        for f, t, c in parts:
            col = table[:, k]
            if f in ("rgb", "rgba") and t.startswith("f"):  # packed float: reinterpret the float32 bits
                col = col.astype(np.float32).view(np.uint32).astype(np.float64)
            columns[f] = col
            k += c
    elif mode == "binary":
        dtype = np.dtype([(f, "<" + t, (c,)) if c > 1 else (f, "<" + t) for f, t, c in parts])
        if pos + n * dtype.itemsize > len(data):
            raise InputError(f"{p.name}: the header says {n} points ({n * dtype.itemsize} bytes); the file is shorter")
        rec = np.frombuffer(data, dtype=dtype, count=n, offset=pos)
        columns = {}
        for f, t, c in parts:
            if c != 1:
                continue
            col = rec[f]
            if f in ("rgb", "rgba") and t.startswith("f"):
                col = col.view(np.uint32)
            columns[f] = col.astype(np.float64)
    else:
        raise InputError(f"{p.name}: PCD DATA {mode!r} is not supported (ascii and binary are)")
    names = [c for c in ("x", "y", "z") if c in columns]
    points = np.column_stack([columns[c] for c in names])
    colors = None
    key = "rgb" if "rgb" in columns else ("rgba" if "rgba" in columns else None)
    if key is not None:
        packed = np.nan_to_num(columns[key]).astype(np.uint32)
        colors = np.column_stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255]) / 255.0
    normals = None
    if {"normal_x", "normal_y", "normal_z"} <= set(columns):
        normals = np.column_stack([columns[c] for c in ("normal_x", "normal_y", "normal_z")])
    if height > 1 and points.shape[1] == 3:
        points = points.reshape(height, width, 3)
        if colors is not None:
            colors = colors.reshape(height, width, 3)
        if normals is not None:
            normals = normals.reshape(height, width, 3)
    return PointCloud(points=points, colors=colors, normals=normals)
