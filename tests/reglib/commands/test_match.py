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
    # --no-dense: no dense stage, so no confidence map
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


def test_summary_prints_the_confidence_and_the_dense_stage(tmp_path, capsys):
    from reglib.examples import example_pair

    a, b = example_pair()
    assert main(["match", str(a), str(b), "--out", str(tmp_path / "cat")]) == 0
    line = capsys.readouterr().out
    body = json.loads((tmp_path / "cat" / "match.json").read_text())
    assert body["converged"] and body["n_dense"] > 0
    assert f"confidence mean {body['confidence']['mean']:.2f}" in line
    assert f"dense kept (+{body['n_dense']} matches)" in line and "(sift), converged" in line
    assert "hint:" not in line and "warning:" not in line
    assert main(["match", str(a), str(b), "--out", str(tmp_path / "off"), "--no-dense"]) == 0
    assert "dense off" in capsys.readouterr().out


def test_a_sift_failure_says_not_converged_and_suggests_auto(images, tmp_path, capsys):
    a, _ = images
    noise = tmp_path / "noise.png"
    noise.write_bytes(io.encode_png(np.random.default_rng(0).integers(0, 256, (256, 320), dtype=np.uint8)))
    assert main(["match", str(a), str(noise), "--out", str(tmp_path / "o"), "--max-keypoints", "400"]) == 0
    out = capsys.readouterr().out
    body = json.loads((tmp_path / "o" / "match.json").read_text())
    assert body["converged"] is False
    assert f"not converged ({body['reason']})" in out and "\nhint:" in out and "--features auto" in out
    # an answer to look at, not to use: the files of its motion are not written, and the line says so
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["match.json", "matches.png", "transform.json"]
    assert "no flow, warped image or overlay written" in out
    assert main(["match", str(a), str(noise), "--out", str(tmp_path / "m"), "--max-keypoints", "400",
                 "--features", "multimodal", "--no-dense"]) == 0
    assert "--features auto" not in capsys.readouterr().out  # the hint is for SIFT alone


@pytest.mark.parametrize("fmt", ["mha", "nrrd", "npy", "nii.gz"])
def test_flow_format_writes_an_itk_displacement_field(images, tmp_path, fmt):
    from reglib import dense_flow

    a, b = images
    out = tmp_path / "out"
    assert main(["match", str(a), str(b), "--out", str(out), "--no-dense", "--max-keypoints", "400",
                 "--flow-format", fmt, "--no-pictures"]) == 0
    assert (out / f"flow.{fmt}").is_file() and not (out / "flow.flo").exists() and (out / "match.json").is_file()
    t = KernelWarp.from_dict(json.loads((out / "transform.json").read_text()))
    flow = io.read_flow(out / f"flow.{fmt}")
    assert np.array_equal(flow, dense_flow(t, (256, 320)))
    assert np.allclose(np.median(flow.reshape(-1, 2), axis=0), [7, -4], atol=0.3)
    # reglib apply writes the same file from match.json (its shape_a gives a's size)
    assert main(["apply", str(out / "match.json"), "--out", str(tmp_path / f"again.{fmt}")]) == 0
    assert np.array_equal(io.read_flow(tmp_path / f"again.{fmt}"), flow)


def test_a_converged_answer_without_support_is_flagged(images, tmp_path):
    """The case a new user met: features=multimodal converged, yet its confidence mean was 0.0."""
    from pathlib import Path

    from reglib.commands.match import summary
    from reglib.matching import ImageMatch, MatchRequest

    a, b = images
    assert main(["match", str(a), str(b), "--out", str(tmp_path / "o"), "--no-dense", "--max-keypoints", "400"]) == 0
    body = json.loads((tmp_path / "o" / "match.json").read_text())
    assert body["converged"]
    body.update(features="multimodal", n_dense=0, confidence={"mean": 0.0, "supported_share": 0.0, "overlap": 1.0})
    request = MatchRequest.from_fields({"features": "multimodal"}, what="test")
    line = summary(ImageMatch.from_dict(body), request, Path("o"))
    assert "(multimodal), converged, confidence mean 0.00 (0 % supported), dense not kept" in line
    assert "\nwarning: the images hardly support this answer" in line and "--features auto" not in line
