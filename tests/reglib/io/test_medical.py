"""2-D NIfTI, MetaImage and NRRD images in: read as stored, every band, told by their bytes; a volume refused."""
from __future__ import annotations

import gzip
import struct
import zlib

import numpy as np
import pytest

from reglib import io
from reglib.errors import InputError


def _grey(dtype=np.int16, shape=(7, 9)):
    return (np.arange(shape[0] * shape[1]).reshape(shape) * 37 - 300).astype(dtype)


def nifti_bytes(arr: np.ndarray, dims=None, *, datatype=4, slope=1.0, inter=0.0, compress=False) -> bytes:
    """A NIfTI-1 file of a grey int16 image by hand: dim (2, W, H), values after the 352-byte header."""
    h, w = arr.shape[:2]
    dims = dims or (2, w, h)
    head = bytearray(352)
    struct.pack_into("<i", head, 0, 348)
    struct.pack_into("<8h", head, 40, *(list(dims) + [1] * (8 - len(dims))))
    struct.pack_into("<hh", head, 70, datatype, 8 * arr.dtype.itemsize)
    struct.pack_into("<fff", head, 108, 352.0, slope, inter)
    head[344:348] = b"n+1\x00"
    data = bytes(head) + np.ascontiguousarray(arr, arr.dtype.newbyteorder("<")).tobytes()
    return gzip.compress(data) if compress else data


def mha_bytes(arr: np.ndarray, *, met="MET_SHORT", msb=False, compress=False, dims=None, data_file="LOCAL") -> bytes:
    h, w = arr.shape[:2]
    channels = 1 if arr.ndim == 2 else arr.shape[2]
    values = np.ascontiguousarray(arr, arr.dtype.newbyteorder(">" if msb else "<")).tobytes()
    if compress:
        values = zlib.compress(values)
    dim = dims or (w, h)
    head = (f"ObjectType = Image\nNDims = {len(dim)}\nBinaryData = True\nBinaryDataByteOrderMSB = {msb}\n"
            f"CompressedData = {compress}\nElementSpacing = 0.5 2\nDimSize = {' '.join(map(str, dim))}\n"
            f"ElementNumberOfChannels = {channels}\nElementType = {met}\nElementDataFile = {data_file}\n")
    return head.encode() + (values if data_file == "LOCAL" else b"")


def nrrd_bytes(arr: np.ndarray, *, kind="short", encoding="raw", sizes=None) -> bytes:
    h, w = arr.shape[:2]
    values = np.ascontiguousarray(arr, arr.dtype.newbyteorder("<")).tobytes()
    if encoding == "gzip":
        values = gzip.compress(values)
    if sizes is None:
        sizes = (w, h) if arr.ndim == 2 else (arr.shape[2], w, h)
    kinds = " ".join(["domain"] * len(sizes)) if arr.ndim == 2 else "vector domain domain"
    head = (f"NRRD0004\ntype: {kind}\ndimension: {len(sizes)}\nsizes: {' '.join(map(str, sizes))}\n"
            f"kinds: {kinds}\nendian: little\nencoding: {encoding}\n\n")
    return head.encode() + values


@pytest.mark.parametrize("compress", [False, True])
def test_nifti_by_hand(compress):
    arr = _grey()
    data = nifti_bytes(arr, compress=compress)
    assert io.image_format(data) == "nifti" and io.image_size(data) == (9, 7)
    out = io.read_image(data)
    assert out.dtype == np.int16 and np.array_equal(out, arr)


def test_nifti_scale_is_applied():
    out = io.read_image(nifti_bytes(_grey(), slope=0.5, inter=10.0))
    np.testing.assert_allclose(out, _grey() * 0.5 + 10.0)


@pytest.mark.parametrize(("msb", "compress"), [(False, False), (True, False), (False, True)])
def test_metaimage_by_hand(msb, compress):
    arr = _grey(np.uint16) + 400
    data = mha_bytes(arr, met="MET_USHORT", msb=msb, compress=compress)
    assert io.image_format(data) == "metaimage"
    out = io.read_image(data)
    assert out.dtype == np.uint16 and np.array_equal(out, arr)


def test_metaimage_bands_and_mhd_with_its_raw_file(tmp_path):
    rgb = np.stack([_grey(np.uint8), _grey(np.uint8) // 2, 255 - _grey(np.uint8)], axis=2)
    assert np.array_equal(io.read_image(mha_bytes(rgb, met="MET_UCHAR")), rgb)
    arr = _grey(np.float32) / 7
    (tmp_path / "x.mhd").write_bytes(mha_bytes(arr, met="MET_FLOAT", data_file="x.raw"))
    (tmp_path / "x.raw").write_bytes(arr.astype("<f4").tobytes())
    assert np.array_equal(io.read_image(tmp_path / "x.mhd"), arr)
    with pytest.raises(InputError, match="separate file 'x.raw'"):
        io.read_image((tmp_path / "x.mhd").read_bytes())


@pytest.mark.parametrize("encoding", ["raw", "gzip"])
def test_nrrd_by_hand(encoding):
    arr = _grey(np.int16)
    data = nrrd_bytes(arr, encoding=encoding)
    assert io.image_format(data) == "nrrd" and io.image_size(data) == (9, 7)
    assert np.array_equal(io.read_image(data), arr)
    bands = np.stack([arr, -arr, arr * 2, arr + 1], axis=2)
    assert np.array_equal(io.read_image(nrrd_bytes(bands, encoding=encoding)), bands)


@pytest.mark.parametrize("encode", [lambda f: io.encode_nifti(f), lambda f: io.encode_nifti(f, compress=False),
                                    io.encode_mha, io.encode_nrrd])
def test_our_displacement_writers_read_back_as_two_band_images(encode):
    flow = np.random.default_rng(3).normal(0, 4, (6, 11, 2)).astype(np.float32)
    out = io.read_image(encode(flow))
    assert out.dtype == np.float32 and out.shape == (6, 11, 2) and np.array_equal(out, flow)


@pytest.mark.parametrize("data", [
    nifti_bytes(np.zeros((3, 4, 5), np.int16), dims=(3, 5, 4, 3)),
    mha_bytes(np.zeros((3, 4, 5), np.int16), dims=(5, 4, 3)),
    nrrd_bytes(np.zeros((4, 5), np.int16), sizes=(5, 4, 3)),
], ids=["nifti", "metaimage", "nrrd"])
def test_a_volume_is_refused_naming_its_size(data):
    with pytest.raises(InputError, match=r"3-D .*volume of 5 x 4 x 3 pixels; reglib registers 2-D images"):
        io.read_image(data)
    with pytest.raises(InputError, match="5 x 4 x 3"):
        io.check_image_header(data)


def test_a_slice_of_one_and_unread_layouts():
    arr = _grey()
    assert np.array_equal(io.read_image(nifti_bytes(arr, dims=(3, 9, 7, 1))), arr)
    with pytest.raises(InputError, match="datatype 32"):
        io.read_image(nifti_bytes(arr, datatype=32))  # complex
    with pytest.raises(InputError, match="data hold"):
        io.read_image(nifti_bytes(arr)[:-10])
    assert io.image_format(gzip.compress(b"just some text" * 40)) is None


@pytest.mark.parametrize("suffix", [".nii.gz", ".nii", ".mha", ".nrrd", ".mhd"])
@pytest.mark.parametrize(("dtype", "bands"), [(np.int16, 1), (np.float64, 1), (np.uint16, 4), (np.uint8, 3)])
@pytest.mark.parametrize("compress", [False, True])
def test_files_written_by_simpleitk(tmp_path, suffix, dtype, bands, compress):
    sitk = pytest.importorskip("SimpleITK")
    grey = _grey(dtype) if dtype != np.uint8 else _grey(np.int16).astype(np.uint8)
    arr = grey if bands == 1 else np.stack([grey + k for k in range(bands)], axis=2).astype(dtype)
    image = sitk.GetImageFromArray(arr, isVector=bands > 1)
    image.SetSpacing((0.7, 1.3))  # not read: the grid is the pixels as stored
    path = tmp_path / f"x{suffix}"
    sitk.WriteImage(image, str(path), compress)
    out = io.read_image(path)
    assert out.dtype == arr.dtype and np.array_equal(out, sitk.GetArrayFromImage(sitk.ReadImage(str(path))))
