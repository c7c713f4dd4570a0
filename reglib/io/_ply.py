"""PLY point files (ascii, binary little or big endian): the header as a record, then one reader per body format.

Only the ``vertex`` element is read: x, y[, z], optional red / green / blue and nx / ny / nz.
Elements before it are skipped (in binary files they must not hold list properties, whose size
is only known by reading them).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._cloud import PointCloud, element_count, points_from, stack_columns

__all__ = ["read_ply"]

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
_BYTE_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">"}
_SKIPPED = ("comment", "obj_info")  # header lines that say nothing about the data


@dataclass(frozen=True)
class _Element:
    """One ``element`` of the header: its count, its scalar properties (name, numpy type) and whether it has lists."""

    name: str
    count: int
    props: tuple[tuple[str, str], ...] = ()
    has_list: bool = False


@dataclass(frozen=True)
class _Header:
    """What the body readers need: the format, the vertex element, the elements before it and where the body starts."""

    fmt: str
    vertex: _Element
    before: tuple[_Element, ...]
    body_start: int


def read_ply(p: Path) -> PointCloud:
    """The vertices of a PLY file, with their colours and normals when it has them."""
    data = p.read_bytes()
    head = _parse_header(data, p.name)
    columns = _BODY_READERS[head.fmt](data, head, p.name)
    return PointCloud(points=points_from(columns), colors=_colors(columns, dict(head.vertex.props)),
                      normals=stack_columns(columns, ("nx", "ny", "nz")))


def _parse_header(data: bytes, name: str) -> _Header:
    """The header of ``data`` (a whole PLY file), checked: a known format and a vertex element with x and y."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise InputError(f"{name}: not a PLY file (no 'ply' magic or no end_header)")
    body_start = data.index(b"\n", end) + 1
    fmt = None
    elements: list[_Element] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in _SKIPPED:
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            elements.append(_Element(name=words[1], count=element_count(words[2], name)))
        elif words[0] == "property" and elements:
            elements[-1] = _with_property(elements[-1], words, line, name)
    return _checked(fmt, elements, body_start, name)


def _with_property(element: _Element, words: list[str], line: str, name: str) -> _Element:
    """``element`` after one more ``property`` line: a list marks it, a scalar of a known type is added."""
    if words[1] == "list":
        return replace(element, has_list=True)
    if words[1] in _PLY_TYPES and len(words) == 3:
        return replace(element, props=element.props + ((words[2], _PLY_TYPES[words[1]]),))
    raise InputError(f"{name}: unknown PLY property line {line!r}")


def _checked(fmt: str | None, elements: list[_Element], body_start: int, name: str) -> _Header:
    """The header record, once the format is known and the (first) vertex element has x, y and no lists."""
    if fmt not in ("ascii", *_BYTE_ORDER):
        raise InputError(f"{name}: unknown PLY format {fmt!r}")
    at = next((k for k, e in enumerate(elements) if e.name == "vertex"), None)
    if at is None or not {"x", "y"} <= {n for n, _ in elements[at].props}:
        raise InputError(f"{name}: PLY header needs a vertex element with x and y properties")
    if elements[at].has_list:
        raise InputError(f"{name}: list properties in the PLY vertex element are not supported")
    return _Header(fmt=fmt, vertex=elements[at], before=tuple(elements[:at]), body_start=body_start)


def _ascii_columns(data: bytes, head: _Header, name: str) -> dict[str, np.ndarray]:
    """The vertex properties of an ascii body, one line a vertex (values past the properties ignored)."""
    n, props = head.vertex.count, head.vertex.props
    lines = data[head.body_start:].decode("ascii", errors="replace").split("\n")
    skip = sum(e.count for e in head.before)  # one line per element before the vertices
    try:
        table = np.array([r.split()[:len(props)] for r in lines[skip:skip + n]], dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{name}: malformed PLY vertex data: {exc}") from None
    if table.shape != (n, len(props)):
        raise InputError(f"{name}: the header says {n} vertices of {len(props)} values, the data differ")
    return {prop: table[:, k] for k, (prop, _) in enumerate(props)}


def _binary_columns(data: bytes, head: _Header, name: str) -> dict[str, np.ndarray]:
    """The vertex properties of a binary body in the header's byte order, as float64."""
    n, props = head.vertex.count, head.vertex.props
    offset = head.body_start + sum(_element_bytes(e, name) for e in head.before)
    order = _BYTE_ORDER[head.fmt]
    dtype = np.dtype([(prop, order + t) for prop, t in props])
    if offset + n * dtype.itemsize > len(data):
        raise InputError(f"{name}: the header says {n} vertices ({n * dtype.itemsize} bytes); the file is shorter")
    rec = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
    return {prop: rec[prop].astype(np.float64) for prop, _ in props}


def _element_bytes(element: _Element, name: str) -> int:
    """Bytes a binary element before the vertices takes; one with list properties has no fixed size: refused."""
    if element.has_list:
        raise InputError(f"{name}: element {element.name!r} with list properties before the vertices is not supported")
    return element.count * sum(np.dtype(t).itemsize for _, t in element.props)


_BODY_READERS: dict[str, Callable[[bytes, _Header, str], dict[str, np.ndarray]]] = {
    "ascii": _ascii_columns, "binary_little_endian": _binary_columns, "binary_big_endian": _binary_columns}


def _colors(columns: dict[str, np.ndarray], kinds: dict[str, str]) -> np.ndarray | None:
    """RGB in [0, 1], or None without red, green and blue: 8-bit types, and values past 1, are read as 0..255."""
    rgb = stack_columns(columns, ("red", "green", "blue"))
    if rgb is None:
        return None
    return rgb / (255.0 if kinds["red"] in ("u1", "i1") or rgb.max(initial=0) > 1 else 1.0)
