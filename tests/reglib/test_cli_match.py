"""Tests of ``reglib match`` and ``reglib apply`` (in-process, through reglib.cli.main)."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import KernelWarp, io
from reglib.cli import main


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    d = tmp_path_factory.mktemp("imgs")
    a = skimage.data.camera()[:256, :320]
    b = cv2.warpAffine(a, np.float32([[1, 0, 7], [0, 1, -4]]), (320, 256))  # b(p + (7, -4)) = a(p)
    (d / "a.png").write_bytes(io.encode_png(a))
    (d / "b.png").write_bytes(io.encode_png(b))
    return d / "a.png", d / "b.png"


def test_match_writes_the_folder(images, tmp_path, capsys):
    a, b = images
    out = tmp_path / "out"
    assert main(["match", str(a), str(b), "--out", str(out), "--no-dense", "--max-keypoints", "400"]) == 0
    line = capsys.readouterr().out
    assert "inliers" in line and str(out) in line
    names = sorted(p.name for p in out.iterdir())
    assert names == ["flow.flo", "match.json", "matches.png", "overlay.png", "transform.json", "warped.png"]
    body = json.loads((out / "match.json").read_text())
    assert body["n_inliers"] > 20 and body["seed"] == 0
    flow = io.read_flo(out / "flow.flo")
    assert flow.shape == (256, 320, 2)
    assert np.allclose(np.median(flow.reshape(-1, 2), axis=0), [7, -4], atol=0.3)
    t = KernelWarp.from_dict(json.loads((out / "transform.json").read_text()))
    assert np.allclose(t(np.array([[100.0, 100.0]])), [[107, 96]], atol=1.0)


def test_match_bad_input_is_one_line_exit_2(images, tmp_path, capsys):
    a, _ = images
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image at all")
    assert main(["match", str(a), str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "image_b" in err and "Traceback" not in err
    assert main(["match", str(a), str(a), "--out", str(tmp_path / "o"), "--filter-options", "{nope"]) == 2
    assert "--filter-options" in capsys.readouterr().err
    assert not (tmp_path / "o" / "match.json").exists()


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


def test_quick_start_on_the_bundled_example(tmp_path, capsys):
    from reglib.examples import example_pair

    a, b = example_pair()
    assert a.is_file() and b.is_file()
    assert main(["match", str(a), str(b), "--out", str(tmp_path / "cat")]) == 0
    body = json.loads((tmp_path / "cat" / "match.json").read_text())
    assert body["n_inliers"] > 50 and body["converged"] is not None and body["fold_fraction"] < 0.01
