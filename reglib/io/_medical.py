"""2-D medical images in: NIfTI-1 (``.nii``, ``.nii.gz``), MetaImage (``.mha``, ``.mhd`` + raw) and NRRD.

Read here without a dependency, beside the writers of displacement fields in these formats
(:mod:`reglib.io._displacement`): a binary (NIfTI, 348 bytes) or text header, then the raw or
zlib / gzip-compressed values. The format is told from the bytes, not the file name: NIfTI by
its magic ``n+1`` at byte 344 (inside a gzip stream for ``.nii.gz``), MetaImage by a first line
``ObjectType`` / ``NDims``, NRRD by ``NRRD000``.

Image registration here is 2-D: a file holds one 2-D slice (extra axes of size 1 are dropped);
a 3-D volume is refused naming its size. Components (NIfTI's 5th axis, MetaImage's
``ElementNumberOfChannels``, a NRRD vector axis) are the image's bands. The pixel grid is taken
as stored, row j and column i of the file (the array SimpleITK's ``GetArrayFromImage`` gives):
spacing, origin and direction are not read, because the transforms map pixels to pixels.
NIfTI's ``scl_slope`` / ``scl_inter``, when they change values, are applied (floats then).
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._displacement import _inflate, _mha_fields, _need, _nrrd_fields, _numbers

__all__ = ["MEDICAL_FORMATS", "MedicalHeader", "medical_format", "medical_header", "decode_medical"]

MEDICAL_FORMATS = ("nifti", "metaimage", "nrrd")
_NIFTI_HEADER = 348
# NIfTI datatype code -> (numpy type without byte order, values per pixel interleaved)
_NIFTI_TYPES = {2: ("u1", 1), 4: ("i2", 1), 8: ("i4", 1), 16: ("f4", 1), 64: ("f8", 1), 256: ("i1", 1),
                512: ("u2", 1), 768: ("u4", 1), 1024: ("i8", 1), 1280: ("u8", 1), 128: ("u1", 3), 2304: ("u1", 4)}
_MET_TYPES = {"MET_UCHAR": "u1", "MET_CHAR": "i1", "MET_USHORT": "u2", "MET_SHORT": "i2", "MET_UINT": "u4",
              "MET_INT": "i4", "MET_ULONG": "u4", "MET_LONG": "i4", "MET_ULONG_LONG": "u8", "MET_LONG_LONG": "i8",
              "MET_FLOAT": "f4", "MET_DOUBLE": "f8"}
_NRRD_TYPES = {
    **dict.fromkeys(("uchar", "unsigned char", "uint8", "uint8_t"), "u1"),
    **dict.fromkeys(("signed char", "int8", "int8_t"), "i1"),
    **dict.fromkeys(("short", "short int", "signed short", "signed short int", "int16", "int16_t"), "i2"),
    **dict.fromkeys(("ushort", "unsigned short", "unsigned short int", "uint16", "uint16_t"), "u2"),
    **dict.fromkeys(("int", "signed int", "int32", "int32_t"), "i4"),
    **dict.fromkeys(("uint", "unsigned int", "uint32", "uint32_t"), "u4"),
    **dict.fromkeys(("longlong", "long long", "long long int", "signed long long", "signed long long int", "int64",
                     "int64_t"), "i8"),
    **dict.fromkeys(("ulonglong", "unsigned long long", "unsigned long long int", "uint64", "uint64_t"), "u8"),
    "float": "f4", "double": "f8"}


@dataclass(frozen=True)
class MedicalHeader:
    """What a medical image's header says: enough to check the size before anything is decoded."""

    format: str  # one of MEDICAL_FORMATS
    width: int
    height: int
    bands: int
    dtype: str  # numpy type with byte order, e.g. "<i2"
    offset: int  # where the values start in the bytes (after the header)
    compressed: bool
    planar: bool  # NIfTI components: every band's plane in turn (else interleaved per pixel)
    data_file: str | None = None  # MetaImage / NRRD values in a separate file, named relative to the header
    scale: tuple[float, float] | None = None  # NIfTI (slope, intercept) when it changes values


def _gunzip_head(data: bytes, size: int) -> bytes:
    """The first ``size`` bytes of a gzip stream (b"" when they cannot be had)."""
    try:
        return zlib.decompressobj(wbits=47).decompress(data[:65536], size)
    except zlib.error:
        return b""


def medical_format(data: bytes) -> str | None:
    """``"nifti"``, ``"metaimage"`` or ``"nrrd"`` from the first bytes of ``data`` (its magic), or None."""
    head = bytes(data[:_NIFTI_HEADER])
    if head[:2] == b"\x1f\x8b":
        head = _gunzip_head(bytes(data), _NIFTI_HEADER)
    if len(head) >= _NIFTI_HEADER and head[344:347] in (b"n+1", b"ni1"):
        return "nifti"
    if head[4:7] == b"n+2":
        return "nifti"
    if head.startswith(b"NRRD000"):
        return "nrrd"
    first = head.split(b"\n", 1)[0].lstrip()
    if first.startswith((b"ObjectType", b"NDims")) and b"=" in first:
        return "metaimage"
    return None


def medical_header(data: bytes, name: str) -> MedicalHeader:
    """The header of a NIfTI-1, MetaImage or NRRD image, checked: one 2-D slice of a known pixel type.

    Raises
    ------
    InputError
        Not one of these formats, a malformed header, a pixel type that is not a real number, a
        3-D volume (its size named) or another layout these readers do not take.
    """
    fmt = medical_format(data)
    if fmt == "nifti":
        return _nifti_header(data, name)
    if fmt == "metaimage":
        return _mha_header(data, name)
    if fmt == "nrrd":
        return _nrrd_header(data, name)
    raise InputError(f"{name}: not a NIfTI, MetaImage or NRRD image")


def _slice_size(sizes: list[int], name: str, what: str) -> tuple[int, int]:
    """(W, H) of a 2-D slice from the spatial sizes (fastest first); extra axes must be 1."""
    if len(sizes) < 2:
        raise InputError(f"{name}: a {len(sizes)}-D {what} image; reglib registers 2-D images")
    if any(s != 1 for s in sizes[2:]):
        shape = " x ".join(str(s) for s in sizes)
        raise InputError(f"{name}: a {len(sizes)}-D {what} volume of {shape} pixels; reglib registers 2-D images "
                         "only: save one slice as a 2-D image")
    w, h = sizes[0], sizes[1]
    if w <= 0 or h <= 0:
        raise InputError(f"{name}: the header says {w}x{h} pixels")
    return w, h


def _nifti_header(data: bytes, name: str) -> MedicalHeader:
    compressed = data[:2] == b"\x1f\x8b"
    head = _gunzip_head(data, _NIFTI_HEADER) if compressed else bytes(data[:_NIFTI_HEADER])
    if head[4:7] == b"n+2":
        raise InputError(f"{name}: NIfTI-2 is not read here; save the slice as NIfTI-1")
    if len(head) < _NIFTI_HEADER:
        raise InputError(f"{name}: too short for a NIfTI-1 header ({len(head)} bytes)")
    order = "<" if struct.unpack("<i", head[:4])[0] == _NIFTI_HEADER else ">"
    if head[344:347] != b"n+1":
        raise InputError(f"{name}: a NIfTI header without its image (a .hdr / .img pair); save it as one .nii")
    dim = struct.unpack(order + "8h", head[40:56])
    datatype = struct.unpack(order + "h", head[70:72])[0]
    if datatype not in _NIFTI_TYPES:
        raise InputError(f"{name}: NIfTI datatype {datatype} is not a real pixel type read here "
                         f"(codes {sorted(_NIFTI_TYPES)})")
    n_dim = int(dim[0])
    if not 1 <= n_dim <= 7:
        raise InputError(f"{name}: NIfTI dim[0] = {n_dim}, not 1..7")
    sizes = [int(v) for v in dim[1:n_dim + 1]]
    comps = sizes[4] if len(sizes) >= 5 else 1  # the 5th axis holds a pixel's components
    w, h = _slice_size(sizes[:4] + sizes[5:], name, "NIfTI")
    kind, per_pixel = _NIFTI_TYPES[datatype]
    offset = int(struct.unpack(order + "f", head[108:112])[0])
    if offset < _NIFTI_HEADER:
        raise InputError(f"{name}: NIfTI vox_offset {offset} lies inside the header")
    slope, inter = (float(v) for v in struct.unpack(order + "ff", head[112:120]))
    changes = np.isfinite(slope) and np.isfinite(inter) and (slope not in (0.0, 1.0) or inter != 0.0)
    return MedicalHeader("nifti", w, h, comps * per_pixel, order + kind, offset, compressed, planar=per_pixel == 1,
                         scale=(slope or 1.0, inter) if changes else None)


def _mha_header(data: bytes, name: str) -> MedicalHeader:
    head, pos = _mha_fields(data, name)
    kind = _need(head, "ElementType", name, "MetaImage")
    if kind not in _MET_TYPES:
        raise InputError(f"{name}: MetaImage ElementType {kind!r} is not read here (one of {sorted(_MET_TYPES)})")
    sizes = [int(v) for v in _numbers(_need(head, "DimSize", name, "MetaImage"), name, "DimSize")]
    ndims = _need(head, "NDims", name, "MetaImage")
    if ndims != str(len(sizes)):
        raise InputError(f"{name}: NDims {ndims} but DimSize {head['DimSize']!r}")
    w, h = _slice_size(sizes, name, "MetaImage")
    msb = head.get("BinaryDataByteOrderMSB", head.get("ElementByteOrderMSB", "False")).lower() == "true"
    if head.get("BinaryData", "True").lower() != "true":
        raise InputError(f"{name}: MetaImage values as text (BinaryData = False) are not read here")
    data_file = head["ElementDataFile"]
    if data_file.upper() in ("LIST",) or "%" in data_file:
        raise InputError(f"{name}: MetaImage values in a list of files ({data_file!r}) are not read here")
    skip = int(head.get("HeaderSize", "0") or 0)
    if skip < 0 and head.get("CompressedData", "False").lower() != "true":
        skip = -1  # the values end the file
    return MedicalHeader("metaimage", w, h, int(head.get("ElementNumberOfChannels", "1")),
                         (">" if msb else "<") + _MET_TYPES[kind], pos if data_file == "LOCAL" else skip,
                         head.get("CompressedData", "False").lower() == "true", planar=False,
                         data_file=None if data_file == "LOCAL" else data_file)


def _nrrd_header(data: bytes, name: str) -> MedicalHeader:
    head, start = _nrrd_fields(data, name)
    kind = _need(head, "type", name, "NRRD").lower()
    if kind not in _NRRD_TYPES:
        raise InputError(f"{name}: NRRD type {kind!r} is not a real pixel type read here")
    sizes = [int(v) for v in _numbers(_need(head, "sizes", name, "NRRD"), name, "sizes")]
    kinds = head.get("kinds", " ".join(["domain"] * len(sizes))).split()
    bands = 1
    if len(sizes) >= 3 and kinds and kinds[0].lower() not in ("domain", "space"):
        bands, sizes = sizes[0], sizes[1:]  # a vector / colour axis first: the bands
    w, h = _slice_size(sizes, name, "NRRD")
    encoding = head.get("encoding", "raw").lower()
    if encoding not in ("raw", "gzip", "gz"):
        raise InputError(f"{name}: NRRD encoding {encoding!r} is not read here (raw or gzip)")
    data_file = head.get("data file", head.get("datafile"))
    if any(int(head.get(k, "0")) != 0 for k in ("line skip", "byte skip")):
        raise InputError(f"{name}: NRRD `line skip` / `byte skip` are not read here")
    dtype = (">" if head.get("endian", "little") == "big" else "<") + _NRRD_TYPES[kind]
    return MedicalHeader("nrrd", w, h, bands, dtype, start if data_file is None else 0, encoding != "raw",
                         planar=False, data_file=data_file)


def decode_medical(data: bytes, name: str, folder: Path | None = None) -> np.ndarray:
    """The (H, W) or (H, W, bands) array of a NIfTI-1, MetaImage or NRRD 2-D image, in its stored type.

    ``folder`` is where a header that names a separate data file (``.mhd`` + ``.raw``, a detached
    NRRD) was read from; without it (bytes, an upload) such a header is an ``InputError``.
    """
    header = medical_header(data, name)
    if header.data_file is not None:
        if folder is None:
            raise InputError(f"{name}: its values are in a separate file {header.data_file!r}; send one file "
                             "(.mha, .nrrd with the data attached, .nii)")
        path = folder / header.data_file
        if not path.is_file():
            raise InputError(f"{name}: its data file {path} does not exist")
        data = path.read_bytes()
    item = np.dtype(header.dtype).itemsize
    want = header.width * header.height * header.bands * item
    if header.compressed:
        stream = zlib.decompressobj(wbits=47)  # zlib or gzip, told by its header
        body = data if header.format == "nifti" else data[max(header.offset, 0):]
        raw = _inflate(stream, body, (header.offset if header.format == "nifti" else 0) + want + 1, name)
        raw = raw[header.offset:] if header.format == "nifti" else raw
    else:
        raw = data[len(data) - want:] if header.offset < 0 else data[header.offset:]
    if len(raw) < want:
        raise InputError(f"{name}: the header says {header.width}x{header.height} pixels of {header.bands} x {item} "
                         f"bytes ({want} bytes); the data hold {len(raw)}")
    values = np.frombuffer(raw[:want], dtype=header.dtype)
    h, w, c = header.height, header.width, header.bands
    image = np.moveaxis(values.reshape(c, h, w), 0, 2) if header.planar else values.reshape(h, w, c)
    image = image.astype(np.dtype(header.dtype).newbyteorder("="))  # native byte order, a writable copy
    if header.scale is not None:
        slope, inter = header.scale
        image = image * np.float32(slope) + np.float32(inter) if item < 8 else image * slope + inter
    return image[:, :, 0] if c == 1 else image
