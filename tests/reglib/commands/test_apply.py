"""Tests of ``reglib apply`` (in-process, through reglib.cli.main)."""
from __future__ import annotations

import json

import numpy as np

from reglib import KernelWarp, io
from reglib.cli import main


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
