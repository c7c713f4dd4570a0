"""Dense flow as an ITK displacement field: MetaImage ``.mha``, NRRD ``.nrrd`` and NIfTI ``.nii`` / ``.nii.gz``.

These are the files medical tools open (ITK, SimpleITK, 3D Slicer, ITK-SNAP, ANTs, elastix's
``transformix``). They are written here with no dependency: a text (or, for NIfTI, a 348-byte
binary) header and the raw little-endian values.

Convention
----------
The flow of image a (``(H_a, W_a, 2)`` float32 of (dx, dy), forward:
``flow[r, c] = f((c, r)) - (c, r)`` for the transform ``f`` that maps a into b, CONTRACTS.md) is
written as a **2-D image of 2-component vectors** (ITK's ``Image<Vector<float, 2>, 2>``) of size
W_a x H_a, with **spacing 1, origin 0 and the identity direction**. ITK's physical point of the
pixel in row r and column c is then (x, y) = (c, r), reglib's own point convention (x the column,
the centre of the top-left pixel at (0, 0)), and the vector stored there is (dx, dy) **in pixels**.

ITK's ``DisplacementFieldTransform`` built from the field maps a point p of image a to
``p + flow(p)``, a point in image b's pixel frame: at pixel centres that is exactly ``f(p)`` (up to
float32 rounding), and between them the field is interpolated linearly. In ITK's registration
words, a is the *fixed* image and b the *moving* one: resampling b (given spacing 1 and origin 0
too) onto a's grid with this transform, ``sitk.Resample(b, a, transform)``, is
``reglib.warp_image(b, f, a.shape)``.

NIfTI stores physical space as RAS where ITK uses LPS: an identity direction in ITK is the NIfTI
``sform`` / ``qform`` diag(-1, -1, 1), which is what is written, and the vectors are stored as ITK
stores them (intent ``NIFTI_INTENT_VECTOR``, components not flipped), so ITK-based tools read the
field above. A tool that reads NIfTI in RAS without ITK's conversion sees x and y negated.
"""
from __future__ import annotations

import gzip
import re
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError

__all__ = ["DISPLACEMENT_SUFFIXES", "check_flow", "displacement_suffix", "encode_mha", "encode_nifti", "encode_nrrd",
           "read_displacement"]

DISPLACEMENT_SUFFIXES = (".mha", ".nrrd", ".nii", ".nii.gz")
_MAX_PIXELS = 1 << 28
_NIFTI_HEADER = 348
_NIFTI_VECTOR = 1007  # intent code NIFTI_INTENT_VECTOR
_NIFTI_TYPES = {16: "<f4", 64: "<f8"}  # NIfTI datatype codes: FLOAT32, FLOAT64


def displacement_suffix(path: str | Path) -> str | None:
    """The displacement-field suffix that ``path`` ends in (lower case, ``.nii.gz`` whole), or None."""
    name = Path(path).name.lower()
    return next((s for s in sorted(DISPLACEMENT_SUFFIXES, key=len, reverse=True) if name.endswith(s)), None)


def _values(flow: np.ndarray) -> bytes:
    """Row by row, x fastest, (dx, dy) interleaved: ITK's order for a vector image, little-endian float32."""
    return np.ascontiguousarray(flow, dtype="<f4").tobytes()


def encode_mha(flow: Any) -> bytes:
    """MetaImage (``.mha``, data inline) bytes of an (H, W, 2) flow: an ITK displacement field (module docstring)."""
    flow = check_flow(flow)
    h, w = flow.shape[:2]
    header = ("ObjectType = Image\nNDims = 2\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
              "CompressedData = False\nTransformMatrix = 1 0 0 1\nOffset = 0 0\nCenterOfRotation = 0 0\n"
              f"ElementSpacing = 1 1\nDimSize = {w} {h}\nElementNumberOfChannels = 2\nElementType = MET_FLOAT\n"
              "ElementDataFile = LOCAL\n")
    return header.encode("ascii") + _values(flow)


def encode_nrrd(flow: Any) -> bytes:
    """NRRD (``.nrrd``, raw, data attached) bytes of an (H, W, 2) flow: an ITK displacement field."""
    flow = check_flow(flow)
    h, w = flow.shape[:2]
    header = ("NRRD0004\n# reglib dense flow: displacement in pixels, (dx, dy) per pixel of image a\n"
              "type: float\ndimension: 3\nspace dimension: 2\n"
              f"sizes: 2 {w} {h}\nspace directions: none (1,0) (0,1)\nkinds: vector domain domain\n"
              "endian: little\nencoding: raw\nspace origin: (0,0)\n\n")
    return header.encode("ascii") + _values(flow)


def encode_nifti(flow: Any, *, compress: bool = True) -> bytes:
    """NIfTI-1 bytes (gzip-compressed for ``.nii.gz`` when ``compress``) of an (H, W, 2) flow.

    dim = (5, W, H, 1, 1, 2): a 2-D field with 2 components (the 5th axis), float32, intent
    ``NIFTI_INTENT_VECTOR``, sform and qform diag(-1, -1, 1) = ITK's identity direction (LPS).
    """
    flow = check_flow(flow)
    h, w = flow.shape[:2]
    head = bytearray(_NIFTI_HEADER + 4)  # header, then 4 bytes saying "no extension"
    struct.pack_into("<i", head, 0, _NIFTI_HEADER)
    head[38:39] = b"r"
    struct.pack_into("<8h", head, 40, 5, w, h, 1, 1, 2, 1, 1)
    struct.pack_into("<hhh", head, 68, _NIFTI_VECTOR, 16, 32)  # intent, datatype FLOAT32, bitpix
    struct.pack_into("<8f", head, 76, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0)  # qfac, spacing
    struct.pack_into("<ff", head, 108, float(_NIFTI_HEADER + 4), 1.0)  # vox_offset, scl_slope
    head[123] = 2  # xyzt_units: mm (ITK's unit for physical space)
    description = b"reglib dense flow (dx, dy) in pixels"
    head[148:148 + len(description)] = description
    struct.pack_into("<hh", head, 252, 1, 1)  # qform_code, sform_code: scanner
    struct.pack_into("<6f", head, 256, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)  # quaternion: 180 degrees about z
    struct.pack_into("<12f", head, 280, -1.0, 0, 0, 0, 0, -1.0, 0, 0, 0, 0, 1.0, 0)
    head[344:348] = b"n+1\x00"
    planes = np.ascontiguousarray(np.moveaxis(np.asarray(flow, dtype="<f4"), 2, 0))  # all dx, then all dy
    data = bytes(head) + planes.tobytes()
    return gzip.compress(data, compresslevel=6, mtime=0) if compress else data


def read_displacement(path: Path) -> np.ndarray:
    """Read a 2-D displacement field (``.mha``, ``.nrrd``, ``.nii``, ``.nii.gz``) into (H, W, 2) float32.

    Files from ITK-based tools are read as well as those written here: float or double
    components, either byte order, MetaImage ``CompressedData`` (zlib), NRRD ``raw`` or ``gzip``,
    gzip-compressed NIfTI. The field must lie on the pixel grid (spacing 1, origin 0, identity
    direction; see the module docstring), since its vectors are read as pixels.

    Raises
    ------
    InputError
        A missing file, a malformed header, a size that disagrees with the data, a field that is
        not 2-D with 2 components, or one on another grid (spacing, origin or direction named).
    """
    if not path.is_file():
        raise InputError(f"no such flow file: {path}")
    suffix = displacement_suffix(path)
    data = path.read_bytes()
    if suffix == ".mha":
        return _read_mha(data, path.name)
    if suffix == ".nrrd":
        return _read_nrrd(data, path.name)
    if suffix in (".nii", ".nii.gz"):
        return _read_nifti(data, path.name)
    raise InputError(f"{path.name}: not a displacement-field file; use one of {list(DISPLACEMENT_SUFFIXES)}")


def check_flow(flow: Any) -> np.ndarray:
    """(H, W, 2) float32 C-contiguous array of a non-empty, finite, numeric flow; an ``InputError`` otherwise."""
    arr = np.asarray(flow)
    if arr.ndim != 3 or arr.shape[2] != 2 or arr.dtype.kind not in "fiu" or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"`flow` must be a non-empty numeric (H, W, 2) array, got {arr.dtype} {arr.shape}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise InputError("`flow` holds NaN or inf values; a displacement field needs a vector at every pixel")
    return np.ascontiguousarray(arr, dtype=np.float32)


def _size(w: int, h: int, name: str) -> int:
    """The pixel count w * h, checked: positive sizes and at most 2**28 pixels."""
    if w <= 0 or h <= 0 or w * h > _MAX_PIXELS:
        raise InputError(f"{name}: implausible field size {w}x{h}")
    return w * h


def _inflate(stream: Any, data: bytes, limit: int, name: str) -> bytes:
    """At most ``limit`` bytes out of a zlib / gzip ``stream`` (so a small file cannot claim a huge field)."""
    try:
        return stream.decompress(data, limit)
    except zlib.error as exc:
        raise InputError(f"{name}: the compressed data cannot be decompressed: {exc}") from None


def _unzip(data: bytes, want: int, name: str) -> bytes:
    """Decompress a zlib or gzip stream (detected from its header), reading at most ``want + 1`` bytes."""
    return _inflate(zlib.decompressobj(wbits=47), data, want + 1, name)  # 47 = 32 + 15: either header


def _field(raw: bytes, dtype: str, w: int, h: int, name: str, planar: bool = False) -> np.ndarray:
    item = np.dtype(dtype).itemsize
    want = w * h * 2 * item
    if len(raw) != want:
        raise InputError(f"{name}: the header says {w}x{h} vectors of 2 x {item} bytes ({want} bytes), "
                         f"the data hold {len(raw)}")
    values = np.frombuffer(raw, dtype=dtype)
    flow = values.reshape(2, h, w).transpose(1, 2, 0) if planar else values.reshape(h, w, 2)
    if not np.isfinite(flow).all():
        raise InputError(f"{name}: the field holds NaN or inf values")
    return np.ascontiguousarray(flow, dtype=np.float32)


def _numbers(text: str, name: str, key: str) -> list[float]:
    try:
        return [float(v) for v in re.findall(r"[^\s(),]+", text)]
    except ValueError:
        raise InputError(f"{name}: bad {key} {text!r}") from None


def _need(head: dict[str, str], key: str, name: str, what: str) -> str:
    if key not in head:
        raise InputError(f"{name}: the {what} header has no `{key}`")
    return head[key]


def _on_pixel_grid(axes: np.ndarray, origin: list[float], name: str) -> None:
    """Refuse a field whose grid is not reglib's pixel grid; ``axes`` (2, 2): the physical step of each axis."""
    spacing = [float(v) for v in np.hypot(axes[:, 0], axes[:, 1])]
    direction = [float(v) for v in (axes / np.maximum(spacing, 1e-300)[:, None]).T.ravel()]
    for what, got, want in (("spacing", spacing, [1.0, 1.0]), ("origin", origin, [0.0, 0.0]),
                            ("direction", direction, [1.0, 0.0, 0.0, 1.0])):
        if len(got) != len(want) or not np.allclose(got, want, atol=1e-6):
            raise InputError(f"{name}: the field's {what} is {got}; reglib reads fields on the pixel grid "
                             f"(spacing 1, origin 0, identity direction), {what} {want}")


def _mha_fields(data: bytes, name: str) -> tuple[dict[str, str], int]:
    """The MetaImage header's fields {key: value} and where the values start (after ``ElementDataFile``)."""
    head: dict[str, str] = {}
    pos = 0
    while "ElementDataFile" not in head:
        end = data.find(b"\n", pos)
        if end < 0 or end - pos > 4096:
            raise InputError(f"{name}: not a MetaImage file (no `ElementDataFile` line)")
        key, eq, value = data[pos:end].decode("ascii", errors="replace").partition("=")
        pos = end + 1
        if eq:
            head[key.strip()] = value.strip()
    return head, pos


def _read_mha(data: bytes, name: str) -> np.ndarray:
    head, pos = _mha_fields(data, name)
    if head["ElementDataFile"] != "LOCAL":
        raise InputError(f"{name}: the data must be in the file (`ElementDataFile = LOCAL`), "
                         f"got {head['ElementDataFile']!r}")
    channels = head.get("ElementNumberOfChannels", "1")
    if _need(head, "NDims", name, "MetaImage") != "2" or channels != "2":
        raise InputError(f"{name}: a flow is a 2-D field of 2-component vectors; the file has NDims "
                         f"{head['NDims']} and {channels} component(s) per pixel")
    kinds = {"MET_FLOAT": "f4", "MET_DOUBLE": "f8"}
    kind = _need(head, "ElementType", name, "MetaImage")
    if kind not in kinds:
        raise InputError(f"{name}: ElementType must be MET_FLOAT or MET_DOUBLE, got {kind!r}")
    msb = head.get("BinaryDataByteOrderMSB", head.get("ElementByteOrderMSB", "False")).lower() == "true"
    dtype = (">" if msb else "<") + kinds[kind]
    dims = _numbers(_need(head, "DimSize", name, "MetaImage"), name, "DimSize")
    if len(dims) != 2:
        raise InputError(f"{name}: DimSize must give 2 sizes, got {head['DimSize']!r}")
    w, h = int(dims[0]), int(dims[1])
    n = _size(w, h, name)
    spacing = _numbers(head.get("ElementSpacing", "1 1"), name, "ElementSpacing")
    matrix = _numbers(head.get("TransformMatrix", head.get("Rotation", "1 0 0 1")), name, "TransformMatrix")
    origin = _numbers(head.get("Offset", head.get("Origin", head.get("Position", "0 0"))), name, "Offset")
    if len(spacing) != 2 or len(matrix) != 4:
        raise InputError(f"{name}: ElementSpacing needs 2 numbers and TransformMatrix 4")
    # MetaImage's TransformMatrix lists the direction matrix column by column: axis 0's direction first
    axes = np.array(matrix).reshape(2, 2) * np.array(spacing)[:, None]
    _on_pixel_grid(axes, origin, name)
    raw = data[pos:]
    if head.get("CompressedData", "False").lower() == "true":
        raw = _unzip(raw, n * 2 * np.dtype(dtype).itemsize, name)
    return _field(raw, dtype, w, h, name)


_NRRD_TYPES = {"float": "f4", "double": "f8"}


def _read_nrrd(data: bytes, name: str) -> np.ndarray:
    """The (H, W, 2) float32 field of NRRD bytes: the header's fields checked in turn, then the attached data."""
    head, start = _nrrd_fields(data, name)
    kind = _nrrd_type(head, name)
    w, h = _nrrd_size(head, name)
    _check_nrrd_kinds(head, name)
    compressed = _nrrd_compressed(head, name)
    n = _size(w, h, name)
    _on_pixel_grid(_nrrd_axes(head, name), _numbers(head.get("space origin", "(0,0)"), name, "space origin"), name)
    dtype = (">" if head.get("endian", "little") == "big" else "<") + kind
    raw = data[start:]
    if compressed:
        raw = _unzip(raw, n * 2 * np.dtype(dtype).itemsize, name)
    return _field(raw, dtype, w, h, name)


def _nrrd_fields(data: bytes, name: str) -> tuple[dict[str, str], int]:
    """The header's fields {key (lower case): value} and where the data start (after the header's blank line)."""
    if not data.startswith(b"NRRD000"):
        raise InputError(f"{name}: not a NRRD file (no NRRD000x magic)")
    end = data.find(b"\n\n")
    if end < 0:
        raise InputError(f"{name}: the NRRD header has no end (a blank line before the data)")
    head: dict[str, str] = {}
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        if line.startswith("#") or ":=" in line:  # comments and key/value pairs
            continue
        key, colon, value = line.partition(":")
        if colon:
            head[key.strip().lower()] = value.strip()
    return head, end + 2


def _nrrd_type(head: dict[str, str], name: str) -> str:
    """The numpy type (kind and bytes, no byte order) of the header's ``type``: float or double."""
    kind = _need(head, "type", name, "NRRD")
    if kind not in _NRRD_TYPES:
        raise InputError(f"{name}: NRRD type must be float or double, got {kind!r}")
    return _NRRD_TYPES[kind]


def _nrrd_size(head: dict[str, str], name: str) -> tuple[int, int]:
    """(W, H) of a field the header says is 3-dimensional with sizes 2 W H."""
    sizes = [int(v) for v in _numbers(_need(head, "sizes", name, "NRRD"), name, "sizes")]
    if _need(head, "dimension", name, "NRRD") != "3" or len(sizes) != 3 or sizes[0] != 2:
        raise InputError(f"{name}: a flow is a 2-D field of 2-component vectors (NRRD sizes 2 W H), "
                         f"got dimension {head['dimension']} and sizes {head['sizes']}")
    return sizes[1], sizes[2]


def _check_nrrd_kinds(head: dict[str, str], name: str) -> None:
    """Refuse axes other than a vector axis first, then two domain (or space) axes."""
    kinds = head.get("kinds", "vector domain domain").split()
    if len(kinds) != 3 or kinds[0] in ("domain", "space") or any(k not in ("domain", "space") for k in kinds[1:]):
        raise InputError(f"{name}: NRRD kinds must be a vector axis, then two domain axes, got {head.get('kinds')!r}")


def _nrrd_compressed(head: dict[str, str], name: str) -> bool:
    """Whether the attached data are gzip-compressed (else raw); detached data and other encodings are refused."""
    if "data file" in head or "datafile" in head:
        raise InputError(f"{name}: detached NRRD data are not read; keep the data in the .nrrd file")
    encoding = head.get("encoding", "raw").lower()
    if encoding not in ("raw", "gzip", "gz"):
        raise InputError(f"{name}: NRRD encoding must be raw or gzip, got {encoding!r}")
    return encoding != "raw"


def _nrrd_axes(head: dict[str, str], name: str) -> np.ndarray:
    """(2, 2) physical step of each domain axis: ``space directions``, else ``spacings`` (1 when neither is given)."""
    if "space directions" in head:
        steps = _numbers(head["space directions"].replace("none", ""), name, "space directions")
    else:
        steps = [v for v in _numbers(head.get("spacings", "nan 1 1"), name, "spacings") if np.isfinite(v)]
        steps = [steps[0], 0.0, 0.0, steps[1]] if len(steps) == 2 else steps
    if len(steps) != 4:
        raise InputError(f"{name}: NRRD space directions must give two 2-D axes, got {steps}")
    return np.array(steps).reshape(2, 2)


def _read_nifti(data: bytes, name: str) -> np.ndarray:
    stream = None
    if data[:2] == b"\x1f\x8b":  # gzip: the header first, then no more bytes than it promises
        stream = zlib.decompressobj(wbits=47)
        data = _inflate(stream, data, _NIFTI_HEADER, name)
    if len(data) < _NIFTI_HEADER:
        raise InputError(f"{name}: too short for a NIfTI-1 header ({len(data)} bytes)")
    order = "<" if struct.unpack("<i", data[:4])[0] == _NIFTI_HEADER else ">"
    if struct.unpack(order + "i", data[:4])[0] != _NIFTI_HEADER or data[344:347] not in (b"n+1", b"ni1"):
        raise InputError(f"{name}: not a NIfTI-1 file (header size or magic)")
    dim = struct.unpack(order + "8h", data[40:56])
    datatype = struct.unpack(order + "h", data[70:72])[0]
    if dim[0] != 5 or dim[3] != 1 or dim[4] != 1 or dim[5] != 2:
        raise InputError(f"{name}: a flow is a 2-D field of 2 components (NIfTI dim (5, W, H, 1, 1, 2)), "
                         f"got dim {dim}")
    if datatype not in _NIFTI_TYPES:
        raise InputError(f"{name}: NIfTI datatype must be float32 (16) or float64 (64), got {datatype}")
    w, h = int(dim[1]), int(dim[2])
    n = _size(w, h, name)
    pixdim = struct.unpack(order + "8f", data[76:108])
    offset = int(struct.unpack(order + "f", data[108:112])[0])
    slope, inter = struct.unpack(order + "ff", data[112:120])
    qform, sform = struct.unpack(order + "hh", data[252:256])
    if sform > 0:  # RAS rows; ITK's LPS negates x and y
        rows = np.array(struct.unpack(order + "12f", data[280:328]), dtype=np.float64).reshape(3, 4)
        axes, origin = -rows[:2, :2].T, [float(v) for v in -rows[:2, 3]]
    else:
        quat = struct.unpack(order + "6f", data[256:280])
        if qform > 0 and not np.allclose(quat, [0, 0, 1, 0, 0, 0], atol=1e-6):
            raise InputError(f"{name}: the NIfTI qform {quat} is not ITK's identity direction with origin 0")
        axes, origin = np.diag(pixdim[1:3]).astype(np.float64), [0.0, 0.0]
    _on_pixel_grid(axes, origin, name)
    item = np.dtype(_NIFTI_TYPES[datatype]).itemsize
    if offset < _NIFTI_HEADER:
        raise InputError(f"{name}: NIfTI vox_offset {offset} lies inside the header")
    if stream is not None:
        data = data + _inflate(stream, stream.unconsumed_tail, offset + n * 2 * item + 1 - len(data), name)
    dtype = order + _NIFTI_TYPES[datatype][1:]
    flow = _field(data[offset:], dtype, w, h, name, planar=True)
    if slope not in (0.0, 1.0) or inter != 0.0:
        flow = (flow * (slope or 1.0) + inter).astype(np.float32)
    return flow
