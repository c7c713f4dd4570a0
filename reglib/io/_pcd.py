"""PCD point files (``DATA ascii`` or ``binary``): the header as a record, then one reader per body format.

x, y[, z], ``rgb`` / ``rgba`` (packed 8-bit channels) and normal_x / y / z are read; an organized
cloud (``HEIGHT`` > 1) keeps its (H, W, 3) grid. ``binary_compressed`` is refused by name.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._cloud import MAX_FILE_POINTS, PointCloud, element_count, points_from, stack_columns

__all__ = ["read_pcd"]

_PCD_KINDS = {"F": "f", "U": "u", "I": "i"}  # TYPE letter -> numpy kind, SIZE giving the bytes
_PACKED = ("rgb", "rgba")  # colour fields holding the channels in one 32-bit value


@dataclass(frozen=True)
class _Field:
    """One field of ``FIELDS``: its name, numpy type (kind and bytes, e.g. ``"f4"``) and ``COUNT`` of values."""

    name: str
    dtype: str
    count: int

    @property
    def packed_float(self) -> bool:
        """A packed colour written as a float: its bits, not its value, hold the channels."""
        return self.name in _PACKED and self.dtype.startswith("f")


@dataclass(frozen=True)
class _Header:
    """What the body readers need: the fields, the grid (``WIDTH`` x ``HEIGHT``), ``DATA`` and where the body starts."""

    fields: tuple[_Field, ...]
    width: int
    height: int
    mode: str
    body_start: int

    @property
    def n(self) -> int:
        """Number of points."""
        return self.width * self.height


def read_pcd(p: Path) -> PointCloud:
    """The points of a PCD file, with their colours and normals when it has them; organized when ``HEIGHT`` > 1."""
    data = p.read_bytes()
    head = _parse_header(data, p.name)
    read_body = _BODY_READERS.get(head.mode)
    if read_body is None:
        raise InputError(f"{p.name}: PCD DATA {head.mode!r} is not supported (ascii and binary are)")
    return _cloud(read_body(data, head, p.name), head)


def _header_lines(data: bytes, name: str) -> tuple[dict[str, list[str]], int]:
    """The header lines up to ``DATA`` as {KEY (upper case): the words after it}, and where the body starts."""
    head: dict[str, list[str]] = {}
    pos = 0
    while True:
        nl = data.find(b"\n", pos)
        if nl < 0:
            raise InputError(f"{name}: not a PCD file (no DATA line)")
        line = data[pos:nl].decode("ascii", errors="replace").strip()
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        words = line.split()
        head[words[0].upper()] = words[1:]
        if words[0].upper() == "DATA":
            return head, pos


def _parse_header(data: bytes, name: str) -> _Header:
    """The header of ``data`` (a whole PCD file), checked: x and y among the fields, known types, a bounded size."""
    head, body_start = _header_lines(data, name)
    try:
        fields = head["FIELDS"]
        sizes = [int(v) for v in head["SIZE"]]
        types = head["TYPE"]
        counts = [int(v) for v in head.get("COUNT", ["1"] * len(fields))]
        width, height = element_count(head["WIDTH"][0], name), element_count(head.get("HEIGHT", ["1"])[0], name)
        mode = head["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as exc:  # element_count's InputError is a ValueError too
        raise InputError(f"{name}: malformed PCD header ({exc})") from None
    if not (len(fields) == len(sizes) == len(types) == len(counts)) or "x" not in fields or "y" not in fields:
        raise InputError(f"{name}: PCD header needs FIELDS with x and y and matching SIZE / TYPE / COUNT")
    if width * height > MAX_FILE_POINTS:
        raise InputError(f"{name}: {width * height} points; at most {MAX_FILE_POINTS} are read")
    try:
        typed = tuple(_Field(name=f, dtype=_PCD_KINDS[t.upper()] + str(s), count=c)
                      for f, s, t, c in zip(fields, sizes, types, counts, strict=True))
    except KeyError:
        raise InputError(f"{name}: unknown PCD TYPE in {types}") from None
    return _Header(fields=typed, width=width, height=height, mode=mode, body_start=body_start)


def _ascii_columns(data: bytes, head: _Header, name: str) -> dict[str, np.ndarray]:
    """Each field's (first) value per point of an ascii body, as float64."""
    text = data[head.body_start:].decode("ascii", errors="replace").split()
    per_point = sum(f.count for f in head.fields)
    if len(text) < head.n * per_point:
        raise InputError(f"{name}: the header says {head.n} points of {per_point} values; the data are shorter")
    table = np.array(text[:head.n * per_point], dtype=np.float64).reshape(head.n, per_point)
    columns: dict[str, np.ndarray] = {}
    k = 0
    for f in head.fields:
        col = table[:, k]
        if f.packed_float:  # reinterpret the float32 bits
            col = col.astype(np.float32).view(np.uint32).astype(np.float64)
        columns[f.name] = col
        k += f.count
    return columns


def _binary_columns(data: bytes, head: _Header, name: str) -> dict[str, np.ndarray]:
    """The single-valued fields of a little-endian binary body, as float64 (fields of several values are skipped)."""
    dtype = np.dtype([(f.name, "<" + f.dtype, (f.count,)) if f.count > 1 else (f.name, "<" + f.dtype)
                      for f in head.fields])
    if head.body_start + head.n * dtype.itemsize > len(data):
        raise InputError(f"{name}: the header says {head.n} points ({head.n * dtype.itemsize} bytes); "
                         "the file is shorter")
    rec = np.frombuffer(data, dtype=dtype, count=head.n, offset=head.body_start)
    return {f.name: (rec[f.name].view(np.uint32) if f.packed_float else rec[f.name]).astype(np.float64)
            for f in head.fields if f.count == 1}


_BODY_READERS: dict[str, Callable[[bytes, _Header, str], dict[str, np.ndarray]]] = {
    "ascii": _ascii_columns, "binary": _binary_columns}


def _cloud(columns: dict[str, np.ndarray], head: _Header) -> PointCloud:
    """The cloud of the columns read: (N, D) points, or an (H, W, 3) grid when ``HEIGHT`` > 1 and the points are 3-D."""
    points = points_from(columns)
    colors = _colors(columns)
    normals = stack_columns(columns, ("normal_x", "normal_y", "normal_z"))
    if head.height > 1 and points.shape[1] == 3:
        grid = (head.height, head.width, 3)
        points = points.reshape(grid)
        colors = None if colors is None else colors.reshape(grid)
        normals = None if normals is None else normals.reshape(grid)
    return PointCloud(points=points, colors=colors, normals=normals)


def _colors(columns: dict[str, np.ndarray]) -> np.ndarray | None:
    """RGB in [0, 1] unpacked from ``rgb`` (else ``rgba``), or None without either."""
    key = next((k for k in _PACKED if k in columns), None)
    if key is None:
        return None
    packed = np.nan_to_num(columns[key]).astype(np.uint32)
    return np.column_stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255]) / 255.0
