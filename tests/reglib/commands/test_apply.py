"""Tests of ``reglib apply`` (in-process, through reglib.cli.main)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from reglib import KernelWarp, io
from reglib.cli import main
from reglib.outputs import FLOW_FORMATS


def test_apply_to_points_and_label_images(tmp_path, capsys):
    t = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.array([3.0, 2.0]), dst_scale=1.0,
                   linear=None, beta=1.0, centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    tf = tmp_path / "t.json"
    tf.write_text(json.dumps(t.to_dict()))
    pts = tmp_path / "p.txt"
    pts.write_text("1 2\n10 20\n")
    assert main(["apply", str(tf), str(pts), "--out", str(tmp_path / "q.txt")]) == 0
    assert np.allclose(np.loadtxt(tmp_path / "q.txt"), [[4, 4], [13, 22]])
    labels = np.zeros((30, 40), np.uint8)
    labels[10:20, 10:30] = 7
    (tmp_path / "l.png").write_bytes(io.encode_png(labels))
    out = tmp_path / "w.png"
    assert main(["apply", str(tf), str(tmp_path / "l.png"), "--out", str(out), "--interpolation", "nearest"]) == 0
    warped = io.read_image(out)
    assert set(np.unique(warped).tolist()) == {0, 7}
    assert np.array_equal(warped[8:28, 7:37] == 7, labels[10:30, 10:40] == 7)
    capsys.readouterr()
    assert main(["apply", str(tmp_path / "missing.json"), str(pts), "--out", str(tmp_path / "x.txt")]) == 2
    assert "no such transform" in capsys.readouterr().err
    # points files go through the point readers: a .npy that is not a numeric array is named, not a traceback
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    assert main(["apply", str(tf), str(tmp_path / "obj.npy"), "--out", str(tmp_path / "y.txt")]) == 2
    assert "obj.npy: not a numeric .npy array" in capsys.readouterr().err
    np.save(tmp_path / "p.npy", np.array([[1.0, 2.0]]))
    assert main(["apply", str(tf), str(tmp_path / "p.npy"), "--out", str(tmp_path / "z.npy")]) == 0
    assert np.allclose(np.load(tmp_path / "z.npy"), [[4, 4]])


def _shift(tmp_path, shape_a=None):
    t = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.array([3.0, 2.0]), dst_scale=1.0,
                   linear=None, beta=1.0, centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    path = tmp_path / ("match.json" if shape_a else "t.json")
    body = {"transform": t.to_dict(), "shape_a": shape_a} if shape_a else t.to_dict()
    path.write_text(json.dumps(body))
    return t, path


@pytest.mark.parametrize("suffix", [".tif", ".tiff", ".bmp", ".png"])
def test_apply_writes_the_image_formats_its_help_lists(tmp_path, suffix):
    _, tf = _shift(tmp_path)
    labels = np.zeros((30, 40), np.uint8)
    labels[10:20, 10:30] = 7
    (tmp_path / "l.png").write_bytes(io.encode_png(labels))
    out = tmp_path / f"w{suffix}"
    assert main(["apply", str(tf), str(tmp_path / "l.png"), "--out", str(out), "--interpolation", "nearest"]) == 0
    warped = io.read_image(out)
    assert io.image_format(out.read_bytes()) == {".bmp": "bmp", ".png": "png"}.get(suffix, "tiff")
    assert np.array_equal(warped[8:28, 7:37] == 7, labels[10:30, 10:40] == 7)


def test_apply_keeps_a_float_image_in_tiff_and_refuses_other_image_suffixes(tmp_path, capsys):
    _, tf = _shift(tmp_path)
    values = np.linspace(0, 50, 30 * 40, dtype=np.float32).reshape(30, 40)
    (tmp_path / "v.tif").write_bytes(io.encode_image(values, ".tif"))
    assert main(["apply", str(tf), str(tmp_path / "v.tif"), "--out", str(tmp_path / "w.tif")]) == 0
    warped = io.read_image(tmp_path / "w.tif")
    assert warped.dtype == np.float32 and np.allclose(warped[:28, :37], values[2:, 3:], atol=1e-4)
    capsys.readouterr()
    assert main(["apply", str(tf), str(tmp_path / "v.tif"), "--out", str(tmp_path / "w.jpg")]) == 2
    err = capsys.readouterr().err
    assert "--out w.jpg: a warped image is written as .png, .tif, .tiff, .bmp" in err
    assert "a flow as " + ", ".join(f".{fmt}" for fmt in FLOW_FORMATS) in err  # the one list, in full
    assert main(["apply", str(tf), "--out", str(tmp_path / "w.txt")]) == 2
    assert ", ".join(f".{fmt}" for fmt in FLOW_FORMATS) in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [f".{fmt}" for fmt in FLOW_FORMATS])
def test_apply_writes_the_flow_on_a_s_frame(tmp_path, suffix, capsys):
    t, match_json = _shift(tmp_path, shape_a=[12, 15])
    out = tmp_path / f"flow{suffix}"
    assert main(["apply", str(match_json), "--out", str(out)]) == 0  # the size from match.json's shape_a
    flow = io.read_flow(out)
    assert flow.shape == (12, 15, 2) and np.allclose(flow, [3.0, 2.0], atol=1e-4)
    _, bare = _shift(tmp_path)
    (tmp_path / "a.png").write_bytes(io.encode_png(np.zeros((8, 9), np.uint8)))
    assert main(["apply", str(bare), str(tmp_path / "a.png"), "--out", str(out)]) == 0  # an image of a's size
    assert io.read_flow(out).shape == (8, 9, 2)
    assert main(["apply", str(bare), "--out", str(out), "--shape-a", "5", "6"]) == 0
    assert io.read_flow(out).shape == (5, 6, 2)
    capsys.readouterr()
    assert main(["apply", str(bare), "--out", str(out)]) == 2
    assert "a flow needs a's size" in capsys.readouterr().err
