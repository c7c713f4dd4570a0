"""Tests of ``reglib match`` (in-process, through reglib.cli.main)."""
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
    assert names == ["confidence.png", "flow.flo", "match.json", "matches.png", "overlay.png", "transform.json",
                     "warped.png"]
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
    assert "`filter` must be a JSON object" in capsys.readouterr().err
    assert not (tmp_path / "o" / "match.json").exists()


def test_quick_start_on_the_bundled_example(tmp_path, capsys):
    from reglib.examples import example_pair

    a, b = example_pair()
    assert a.is_file() and b.is_file()
    assert main(["match", str(a), str(b), "--out", str(tmp_path / "cat")]) == 0
    body = json.loads((tmp_path / "cat" / "match.json").read_text())
    assert body["n_inliers"] > 50 and body["converged"] is not None and body["fold_fraction"] < 0.01


def test_every_request_field_is_a_flag_with_the_library_bounds(images, tmp_path, capsys):
    from reglib.matching import match_request_specs

    a, b = images
    parser_help = __import__("reglib.cli", fromlist=["build_parser"]).build_parser()
    sub = parser_help._subparsers._group_actions[0].choices["match"]
    flags = {opt for action in sub._actions for opt in action.option_strings}
    for spec in match_request_specs():
        assert f"--{spec.name.replace('_', '-')}" in flags, spec.name
        if spec.kind in ("int", "float") and spec.high is not None:
            value = str(int(spec.high) + 1 if spec.kind == "int" else spec.high * 2 + 1)
            assert main(["match", str(a), str(b), "--out", str(tmp_path / "o"),
                         f"--{spec.name.replace('_', '-')}", value]) == 2
            assert f"`{spec.name}`" in capsys.readouterr().err
