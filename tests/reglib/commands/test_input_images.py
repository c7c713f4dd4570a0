"""``reglib match`` and ``reglib apply`` on images as the fields store them: medical 2-D formats, 4+ bands, 16 bits."""
from __future__ import annotations

import gzip
import json
import struct

import cv2
import numpy as np
import pytest

from reglib import io
from reglib.cli import main
from reglib.examples import example_pair


def _nifti_gz(grey: np.ndarray) -> bytes:
    """A gzip-compressed NIfTI-1 file of a 2-D int16 image, built by hand (dim (2, W, H), datatype 4)."""
    head = bytearray(352)
    struct.pack_into("<i", head, 0, 348)
    struct.pack_into("<8h", head, 40, 2, grey.shape[1], grey.shape[0], 1, 1, 1, 1, 1)
    struct.pack_into("<hh", head, 70, 4, 16)
    struct.pack_into("<ff", head, 108, 352.0, 1.0)
    head[344:348] = b"n+1\x00"
    return gzip.compress(bytes(head) + grey.astype("<i2").tobytes())


def _example_grey():
    return [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.int16) * 9 - 400 for p in example_pair()]


def _match_json(folder):
    return json.loads((folder / "match.json").read_text())


def test_match_reads_nifti_written_by_hand(tmp_path, capsys):
    paths = []
    for name, grey in zip("ab", _example_grey(), strict=True):
        paths.append(tmp_path / f"{name}.nii.gz")
        paths[-1].write_bytes(_nifti_gz(grey))
    out = tmp_path / "out.nii.gz"  # a folder, whatever its name
    assert main(["match", *map(str, paths), "--out", str(out)]) == 0
    body = _match_json(out)
    assert body["n_inliers"] >= 20 and body["shape_a"] == list(_example_grey()[0].shape)


@pytest.mark.parametrize("suffix", [".nii.gz", ".mha", ".nrrd"])
def test_match_reads_files_written_by_simpleitk(tmp_path, suffix):
    sitk = pytest.importorskip("SimpleITK")
    paths = []
    for name, grey in zip("ab", _example_grey(), strict=True):
        paths.append(tmp_path / f"{name}{suffix}")
        sitk.WriteImage(sitk.GetImageFromArray(grey), str(paths[-1]))
    out = tmp_path / "dir"
    assert main(["match", *map(str, paths), "--out", str(out)]) == 0
    assert _match_json(out)["n_inliers"] >= 20


def test_match_names_a_volume(tmp_path, capsys):
    sitk = pytest.importorskip("SimpleITK")
    sitk.WriteImage(sitk.GetImageFromArray(np.zeros((5, 30, 40), np.float32)), str(tmp_path / "v.mha"))
    assert main(["match", str(tmp_path / "v.mha"), str(tmp_path / "v.mha"), "--out", str(tmp_path / "o")]) == 2
    assert "3-D MetaImage volume of 40 x 30 x 5 pixels" in capsys.readouterr().err


def test_apply_keeps_four_bands_of_16_bits_of_an_opencv_tiff(tmp_path, shift_json):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 65535, (30, 40, 4), dtype=np.uint16)  # OpenCV tags the 4th channel alpha
    assert cv2.imwrite(str(tmp_path / "img.tif"), img)
    out = tmp_path / "w.tif"
    assert main(["apply", str(shift_json), str(tmp_path / "img.tif"), "--out", str(out)]) == 0
    warped = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert warped.shape == (30, 40, 4) and warped.dtype == np.uint16
    assert np.array_equal(warped[:28, :37], img[2:, 3:])  # every band moved, the 4th too
    assert not warped[28:].any() and not warped[:, 37:].any()


@pytest.mark.parametrize(("dtype", "bands"), [(np.float64, 5), (np.int16, 2), (np.int32, 3)])
def test_apply_keeps_bands_and_dtype_in_tiff(tmp_path, shift_json, dtype, bands):
    img = (np.random.default_rng(1).normal(0, 1000, (30, 40, bands))).astype(dtype)
    (tmp_path / "img.tif").write_bytes(io.encode_image(img, ".tif"))
    assert np.array_equal(io.read_image(tmp_path / "img.tif"), img)
    out = tmp_path / "w.tif"
    assert main(["apply", str(shift_json), str(tmp_path / "img.tif"), "--out", str(out)]) == 0
    warped = io.read_image(out)
    assert warped.dtype == dtype and warped.shape == img.shape
    assert np.array_equal(warped[:28, :37], img[2:, 3:])


def test_apply_reads_a_medical_image_and_refuses_png_for_five_bands(tmp_path, shift_json, capsys):
    grey = (np.arange(30 * 40).reshape(30, 40) - 600).astype(np.int16)
    (tmp_path / "x.nii.gz").write_bytes(_nifti_gz(grey))
    out = tmp_path / "w.tif"
    assert main(["apply", str(shift_json), str(tmp_path / "x.nii.gz"), "--out", str(out)]) == 0
    warped = io.read_image(out)
    assert warped.dtype == np.int16 and np.array_equal(warped[:28, :37], grey[2:, 3:])
    (tmp_path / "five.tif").write_bytes(io.encode_image(np.zeros((30, 40, 5), np.uint8), ".tif"))
    five = str(tmp_path / "five.tif")
    assert main(["apply", str(shift_json), five, "--out", str(tmp_path / "w.png")]) == 2
    assert "PNG holds 1, 3 or 4 bands; an image of 5 bands is written as .tif" in capsys.readouterr().err
