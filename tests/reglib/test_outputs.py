"""save_match: which files each combination of images and switches writes, their content, and bad folders named."""
from __future__ import annotations

import json

import numpy as np
import pytest

from reglib import ImageMatch, KernelWarp, dense_flow, warp_image
from reglib.errors import InputError
from reglib.io import read_flow, read_image
from reglib.outputs import MATCH_FILE, save_match
from reglib.visualize import draw_matches, overlay, to_rgb_uint8

SHAPE_A, SHAPE_B = (24, 32), (30, 36)
FILES = {"transform": "transform.json", "flow": "flow.flo", "confidence": "confidence.png", "warped": "warped.png",
         "matches": "matches.png", "overlay": "overlay.png", "match": MATCH_FILE}


def _match(confidence: bool = True) -> ImageMatch:
    """A match whose transform shifts a's pixels by (2, -1) into b, with 5 matches (the last an outlier)."""
    shift = KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.array([2.0, -1.0]), dst_scale=1.0,
                       linear=None, beta=1.0, centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))
    src = np.array([[3.0, 4.0], [10.0, 12.0], [20.0, 5.0], [7.0, 18.0], [25.0, 20.0]])
    dst = shift(src) + np.array([[0.0, 0.0]] * 4 + [[6.0, 3.0]])
    conf = np.random.default_rng(0).uniform(0.0, 1.0, SHAPE_A).astype(np.float32) if confidence else None
    return ImageMatch(keypoints_a=src, keypoints_b=dst, src=src, dst=dst, inliers=np.array([1, 1, 1, 1, 0], bool),
                      scores=np.array([0.9, 0.8, 0.95, 0.7, 0.1]), transform=shift, converged=True, reason=None,
                      seed=0, shape_a=SHAPE_A, shape_b=SHAPE_B, confidence=conf)


@pytest.fixture(scope="module")
def images() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    return rng.integers(0, 256, (*SHAPE_A, 3), dtype=np.uint8), rng.integers(0, 256, SHAPE_B, dtype=np.uint8)


@pytest.mark.parametrize("given, switches, keys", [
    ("", {}, ["transform", "flow", "confidence", "match"]),
    ("ab", {}, ["transform", "flow", "confidence", "warped", "matches", "overlay", "match"]),
    ("b", {}, ["transform", "flow", "confidence", "warped", "match"]),
    ("a", {}, ["transform", "flow", "confidence", "match"]),
    ("ab", {"warped": False}, ["transform", "flow", "confidence", "matches", "overlay", "match"]),
    ("ab", {"pictures": False}, ["transform", "flow", "confidence", "warped", "match"]),
    ("ab", {"warped": False, "pictures": False}, ["transform", "flow", "confidence", "match"]),
    ("ab", {"flow": False, "confidence": False}, ["transform", "warped", "matches", "overlay", "match"]),
    ("b", {"flow": False, "warped": False}, ["transform", "confidence", "match"]),
])
def test_each_switch_and_image_decides_the_files_written(tmp_path, images, given, switches, keys):
    a, b = images
    out = tmp_path / "new" / "folder"  # created with its parents
    written = save_match(_match(), out, image_a=a if "a" in given else None, image_b=b if "b" in given else None,
                         **switches)
    assert list(written) == keys  # match.json last: its presence means the folder is complete
    assert written == {k: out / FILES[k] for k in keys}
    assert sorted(p.name for p in out.iterdir()) == sorted(FILES[k] for k in keys)  # no temporary files left


def test_without_a_confidence_map_no_confidence_file(tmp_path, images):
    written = save_match(_match(confidence=False), tmp_path, image_a=images[0], image_b=images[1])
    assert "confidence" not in written and not (tmp_path / "confidence.png").exists()
    assert list(written) == ["transform", "flow", "warped", "matches", "overlay", "match"]


def test_the_files_hold_the_match_its_flow_confidence_and_pictures(tmp_path, images):
    a, b = images
    m = _match()
    written = save_match(m, tmp_path, image_a=a, image_b=b)
    assert json.loads(written["transform"].read_text()) == m.transform.to_dict()
    assert json.loads(written["match"].read_text()) == json.loads(json.dumps(m.to_dict()))
    assert np.array_equal(read_flow(written["flow"]), dense_flow(m.transform, SHAPE_A))
    assert np.array_equal(read_image(written["flow"].with_name("confidence.png")), np.round(m.confidence * 255.0))
    warped_b, valid = warp_image(b, m.transform, SHAPE_A)
    assert valid.mean() > 0.8 and not valid.all()  # the shift moves part of a outside b: the test can fail
    assert np.array_equal(read_image(written["warped"]), warped_b)
    assert np.array_equal(read_image(written["matches"]), draw_matches(a, b, m))
    assert np.array_equal(read_image(written["overlay"]), overlay(a, warped_b, 0.5))


def test_warped_keeps_8_and_16_bit_images_and_scales_others_to_8_bit_rgb(tmp_path, images):
    m = _match()
    b16 = images[1].astype(np.uint16) * 257
    got = read_image(save_match(m, tmp_path / "u16", image_b=b16)["warped"])
    assert got.dtype == np.uint16 and np.array_equal(got, warp_image(b16, m.transform, SHAPE_A)[0])
    bf = images[1].astype(np.float32) / 255.0
    got = read_image(save_match(m, tmp_path / "f32", image_b=bf)["warped"])
    want = to_rgb_uint8(warp_image(bf, m.transform, SHAPE_A)[0], "warped")
    assert got.dtype == np.uint8 and got.shape == (*SHAPE_A, 3) and np.array_equal(got, want)


def test_bad_folder_and_image_shapes_are_named_and_nothing_is_written(tmp_path, images):
    a, b = images
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="`out_dir` exists and is not a folder: .*file"):
        save_match(_match(), tmp_path / "file")
    with pytest.raises(InputError, match=r"`image_a` has shape \(10, 32\), the match was made on \(24, 32\)"):
        save_match(_match(), tmp_path / "o1", image_a=a[:10], image_b=b[:5])
    with pytest.raises(InputError, match=r"`image_b` has shape \(5, 36\), the match was made on \(30, 36\)"):
        save_match(_match(), tmp_path / "o2", image_a=a, image_b=b[:5])
    with pytest.raises(InputError, match="image_b"):
        save_match(_match(), tmp_path / "o3", image_b=np.zeros((0, 3)))
    assert [list((tmp_path / o).iterdir()) for o in ("o1", "o2", "o3")] == [[], [], []]  # made, left empty


def test_an_unconverged_match_gets_its_evidence_and_transform_only(tmp_path, images):
    """No file that carries the motion (flow, confidence, warped b, overlay) for an answer not to be used."""
    import dataclasses

    from reglib.outputs import writes_motion

    m = dataclasses.replace(_match(), converged=False, reason="too_few_inliers")
    assert not writes_motion(m) and writes_motion(_match())
    written = save_match(m, tmp_path, image_a=images[0], image_b=images[1], flow_format="nrrd")
    assert list(written) == ["transform", "matches", "match"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["match.json", "matches.png", "transform.json"]
