"""Tests of reglib.io: header-checked image reading, format sniffing, flow files, PNG encoding."""
from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from reglib import io
from reglib.errors import ImageTooLarge, InputError, UnsupportedFormat


def _encode(ext: str, img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, img)
    assert ok
    return buf.tobytes()


def _png_header_claiming(w: int, h: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    return b"\x89PNG\r\n\x1a\n" + chunk + b"\x00" * 64


@pytest.mark.parametrize("ext,name", [(".png", "png"), (".jpg", "jpeg"), (".tiff", "tiff"), (".bmp", "bmp"),
                                      (".webp", "webp")])
def test_format_and_size_from_header(ext, name):
    img = np.random.default_rng(0).integers(0, 255, (37, 53, 3), dtype=np.uint8)
    data = _encode(ext, img)
    assert io.image_format(data) == name
    assert io.image_size(data) == (53, 37)


def test_image_format_unknown_and_unsupported():
    assert io.image_format(b"hello world, not an image") is None
    assert io.image_format(b"GIF89a\x01\x00\x01\x00") == "gif"
    assert io.image_size(b"GIF89a\x01\x00\x01\x00") is None


def test_read_image_rgb_order_and_sources(tmp_path):
    img = np.zeros((10, 12, 3), np.uint8)
    img[..., 0] = 200  # red in RGB
    data = io.encode_png(img)
    from_bytes = io.read_image(data)
    assert from_bytes.shape == (10, 12, 3) and from_bytes.dtype == np.uint8
    assert np.array_equal(from_bytes, img)
    path = tmp_path / "x.png"
    path.write_bytes(data)
    assert np.array_equal(io.read_image(path), img)
    assert np.array_equal(io.read_image(str(path)), img)


def test_read_image_keeps_16_bit_and_alpha_as_a_fourth_band():
    img16 = (np.arange(20 * 30, dtype=np.uint16).reshape(20, 30) * 97)
    out = io.read_image(_encode(".png", img16))
    assert out.dtype == np.uint16 and np.array_equal(out, img16)
    bgra = np.random.default_rng(1).integers(0, 255, (8, 9, 4), dtype=np.uint8)
    out = io.read_image(_encode(".png", bgra))  # OpenCV's order is BGRA; read_image answers RGBA
    assert out.shape == (8, 9, 4)
    assert np.array_equal(out, bgra[..., [2, 1, 0, 3]])
    arr = io.read_image(bgra)
    assert arr is bgra


def test_pixel_limit_is_checked_from_the_header_before_decoding():
    bomb = _png_header_claiming(100_000, 100_000)  # claims 10^10 pixels, holds 64 bytes
    with pytest.raises(ImageTooLarge, match="from its header"):
        io.read_image(bomb)
    small = _encode(".png", np.zeros((20, 20), np.uint8))
    with pytest.raises(ImageTooLarge, match="limit of 100"):
        io.read_image(small, max_pixels=100)
    with pytest.raises(ImageTooLarge):
        io.read_image(np.zeros((20, 20)), max_pixels=399)


@pytest.mark.parametrize("data,exc,words", [
    (b"", InputError, "empty"),
    (b"this is just text", InputError, "cannot be decoded"),
    (b"GIF89a" + b"\x00" * 40, UnsupportedFormat, "GIF"),
])
def test_bad_bytes_are_named(data, exc, words):
    with pytest.raises(exc, match=words):
        io.read_image(data, name="image_a")
    with pytest.raises(exc, match="image_a"):
        io.read_image(data, name="image_a")


def test_truncated_png_is_undecodable():
    data = _encode(".png", np.random.default_rng(0).integers(0, 255, (50, 50), dtype=np.uint8))
    with pytest.raises(InputError, match="cannot be decoded"):
        io.read_image(data[: len(data) // 2])


@pytest.mark.parametrize("arr,words", [
    (np.zeros((0, 5)), "empty"),
    (np.zeros((4, 4, 2, 1)), "shape"),
    (np.zeros((4, 4, 0)), "shape"),
    (np.array([[np.nan, 1.0]]), "NaN"),
    (np.array([["a"]]), "dtype"),
])
def test_bad_arrays(arr, words):
    with pytest.raises(InputError, match=words):
        io.read_image(arr)


def test_bad_source_type_and_missing_file(tmp_path):
    with pytest.raises(InputError, match="must be an image array"):
        io.read_image(3.5)
    with pytest.raises(InputError, match="no such file"):
        io.read_image(tmp_path / "nope.png")
    with pytest.raises(InputError, match="max_pixels"):
        io.read_image(np.zeros((3, 3)), max_pixels=0)


def test_one_pixel_and_float_images_are_accepted():
    assert io.read_image(np.ones((1, 1))).shape == (1, 1)
    f = io.read_image(np.random.default_rng(0).random((5, 6, 3)).astype(np.float32))
    assert f.dtype == np.float32 and f.shape == (5, 6, 3)


def test_flo_round_trip_and_header_checks(tmp_path):
    flow = np.random.default_rng(0).normal(size=(7, 11, 2)).astype(np.float32)
    path = tmp_path / "f.flo"
    io.write_flo(path, flow)
    assert path.stat().st_size == 12 + 7 * 11 * 8
    assert np.array_equal(io.read_flo(path), flow)
    # a header claiming more than the file holds is refused before allocating
    bad = tmp_path / "bad.flo"
    bad.write_bytes(struct.pack("<fii", 202021.25, 50_000, 50_000) + b"\x00" * 16)
    with pytest.raises(InputError, match="implausible|header says"):
        io.read_flo(bad)
    bad.write_bytes(struct.pack("<fii", 202021.25, 3, 3) + b"\x00" * 16)
    with pytest.raises(InputError, match="header says 3x3"):
        io.read_flo(bad)
    bad.write_bytes(struct.pack("<fii", 1.0, 3, 3))
    with pytest.raises(InputError, match="magic"):
        io.read_flo(bad)
    bad.write_bytes(b"12")
    with pytest.raises(InputError, match="too short"):
        io.read_flo(bad)


def test_npy_flow_round_trip(tmp_path):
    flow = np.random.default_rng(1).normal(size=(4, 5, 2)).astype(np.float32)
    io.write_flow(tmp_path / "f.npy", flow)
    assert np.array_equal(io.read_flow(tmp_path / "f.npy"), flow)
    np.save(tmp_path / "g.npy", np.zeros((4, 5, 3)))
    with pytest.raises(InputError, match=r"\(H, W, 2\)"):
        io.read_flow(tmp_path / "g.npy")
    with pytest.raises(InputError, match=r"\.flo, \.npy, \.mha, \.nrrd"):
        io.write_flow(tmp_path / "f.txt", flow)
    with pytest.raises(InputError, match="flow"):
        io.write_flo(tmp_path / "h.flo", np.zeros((3, 3)))


def test_encode_png_round_trip_and_atomic_write(tmp_path):
    img = np.random.default_rng(2).integers(0, 255, (6, 7, 3), dtype=np.uint8)
    assert np.array_equal(io.read_image(io.encode_png(img)), img)
    assert io.read_image(io.encode_png(np.ones((3, 3), bool))).max() == 255
    with pytest.raises(InputError, match="non-empty"):
        io.encode_png(np.zeros((0, 3)))
    io.write_bytes_atomic(tmp_path / "sub" / "x.bin", b"abc")
    assert (tmp_path / "sub" / "x.bin").read_bytes() == b"abc"
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["x.bin"]


def test_flow_bytes_are_the_files_bytes(tmp_path):
    flow = np.random.default_rng(0).normal(size=(7, 9, 2)).astype(np.float32)
    io.write_flo(tmp_path / "f.flo", flow)
    assert io.encode_flo(flow) == (tmp_path / "f.flo").read_bytes()
    io.write_flow(tmp_path / "f.npy", flow)
    assert np.array_equal(np.load(__import__("io").BytesIO(io.encode_npy(flow))), io.read_flow(tmp_path / "f.npy"))


def test_a_header_without_a_size_is_refused_before_decoding():
    data = io.encode_png(np.zeros((8, 8), np.uint8))
    broken = data[:16] + b"XXXX" + data[20:]  # IHDR tag damaged: no size from the header
    with pytest.raises(InputError, match="header"):
        io.read_image(broken)


@pytest.mark.parametrize("suffix", [".png", ".tif", ".tiff", ".bmp"])
def test_encode_image_by_suffix_keeps_label_values(suffix):
    labels = np.zeros((9, 12), np.uint8)
    labels[2:6, 3:9] = 7
    rgb = np.random.default_rng(3).integers(0, 256, (9, 12, 3), dtype=np.uint8)
    for img in (labels, rgb):
        data = io.encode_image(img, suffix)
        assert io.image_format(data) == {".png": "png", ".bmp": "bmp"}.get(suffix, "tiff")
        assert np.array_equal(io.read_image(data), img)


def test_encode_image_keeps_16_bit_and_float_where_the_format_can():
    deep = np.arange(12 * 9, dtype=np.uint16).reshape(9, 12) * 500
    for suffix in (".png", ".tif"):
        assert np.array_equal(io.read_image(io.encode_image(deep, suffix)), deep)
    values = np.linspace(-3, 7, 108, dtype=np.float32).reshape(9, 12)
    got = io.read_image(io.encode_image(values, ".tif"))
    assert got.dtype == np.float32 and np.array_equal(got, values)
    with pytest.raises(InputError, match="BMP holds 8 bits"):
        io.encode_image(deep, ".bmp")
    with pytest.raises(InputError, match=r"\.png, \.tif, \.tiff, \.bmp"):
        io.encode_image(deep, ".jpg")
