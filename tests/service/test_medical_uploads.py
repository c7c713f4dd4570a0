"""Uploads of 2-D medical images (told by their bytes, not their names) and of multi-band TIFFs."""
from __future__ import annotations

import gzip
import struct

import cv2
import numpy as np

from reglib import io
from reglib.examples import example_pair
from service.problems import UNDECODABLE_IMAGE


def _nifti_gz(arr: np.ndarray, dims=None) -> bytes:
    head = bytearray(352)
    struct.pack_into("<i", head, 0, 348)
    dims = dims or (2, arr.shape[1], arr.shape[0])
    struct.pack_into("<8h", head, 40, *(list(dims) + [1] * (8 - len(dims))))
    struct.pack_into("<hh", head, 70, 4, 16)
    struct.pack_into("<ff", head, 108, 352.0, 1.0)
    head[344:348] = b"n+1\x00"
    return gzip.compress(bytes(head) + arr.astype("<i2").tobytes())


def _mha(arr: np.ndarray) -> bytes:
    head = (f"ObjectType = Image\nNDims = 2\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
            f"DimSize = {arr.shape[1]} {arr.shape[0]}\nElementType = MET_SHORT\nElementDataFile = LOCAL\n")
    return head.encode() + arr.astype("<i2").tobytes()


def _post(client, data_a, data_b, path="/v1/match"):
    files = {"image_a": ("upload.bin", data_a, "application/octet-stream"),
             "image_b": ("upload.bin", data_b, "application/octet-stream")}
    return client.post(path, files=files, data={"dense": "false"})


def _greys():
    return [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.int16) * 9 - 400 for p in example_pair()]


def test_nifti_and_metaimage_uploads_match(client):
    a, b = _greys()
    for encode in (_nifti_gz, _mha):
        r = _post(client, encode(a), encode(b))
        assert r.status_code == 200, r.text
        assert r.json()["n_inliers"] >= 20 and r.json()["shape_a"] == list(a.shape)


def test_a_volume_upload_is_refused_naming_its_size(client):
    vol = _nifti_gz(np.zeros((3, 20, 30), np.int16), dims=(3, 30, 20, 3))
    r = _post(client, vol, vol)
    assert r.status_code == 400 and r.json()["type"] == UNDECODABLE_IMAGE
    assert "volume of 30 x 20 x 3 pixels" in r.json()["detail"]


def test_a_five_band_tiff_warps_to_a_png_picture(client):
    a, b = (cv2.imread(str(p)) for p in example_pair())
    five = [io.encode_image(np.dstack([x, x[:, :, :2]]).astype(np.uint16) * 100, ".tif") for x in (a, b)]
    r = _post(client, *five, path="/v1/warp")
    assert r.status_code == 200, r.text
    assert io.read_image(r.content).shape == a.shape
