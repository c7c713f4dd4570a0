"""Tests of reglib.dense._confidence: the support check, the confidence map and its summary, in match_images' answer
and files."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import ImageMatch, KernelWarp, dense_flow, match_images
from reglib.dense import DenseOptions, confidence_map, confidence_summary, found_away
from reglib.dense._confidence import AWAY_PX, check_support, supported
from reglib.dense._correlation import on_lattice
from reglib.errors import InputError


def test_a_check_every_other_grid_point_is_the_lattice_of_the_full_check():
    # the guard checks its re-fit on f0's lattice and compares it there with the full grid's
    # evidence: the two searches must agree exactly at the shared points
    a = skimage.data.camera().astype(np.float32)
    b = cv2.warpAffine(a, np.float32([[1, 0, 2.3], [0, 1, -1.4]]), (512, 512), flags=cv2.INTER_CUBIC)
    f = KernelWarp.identity(2)
    fa, fb = a[:, :, None], b[:, :, None]
    full, half = check_support(fa, fb, f, 16, 5), check_support(fa, fb, f, 32, 5)
    on = on_lattice(full.grid, 32, 5)
    assert 0 < on.sum() < len(full.grid)
    np.testing.assert_array_equal(full.grid[on], half.grid)
    np.testing.assert_array_equal(full.found[on], half.found)
    np.testing.assert_array_equal(full.offset[on], half.offset)
    assert half.found.mean() > 0.8


def test_supported_grid_points_are_those_whose_match_lands_near_the_transform(make_affine):
    a = skimage.data.camera().astype(np.float32)
    b = cv2.warpAffine(a, np.float32([[1, 0, 2.0], [0, 1, 1.0]]), (512, 512), flags=cv2.INTER_CUBIC)
    fa, fb = a[:, :, None], b[:, :, None]
    right, off = make_affine([[1, 0, 2.0], [0, 1, 1.0]]), make_affine([[1, 0, 4.0], [0, 1, 1.0]])
    s = check_support(fa, fb, right, 16, 5)
    sup = supported(s, right, right)
    assert sup.shape == (len(s.grid),) and sup.dtype == bool and sup.mean() > 0.5
    assert not (sup & ~s.found).any()  # support needs a match
    # the same matches judged against a transform 2 px away: none within 1 px of it
    assert not supported(s, right, off).any()
    empty = check_support(fa[:8, :8], fb[:8, :8], right, 16, 5)
    assert supported(empty, right, right).shape == (0,)


def test_confidence_map_shape_range_and_meaning(make_affine):
    a = skimage.data.camera().astype(np.float32)
    t = [2.0, 1.0]
    b = cv2.warpAffine(a, np.float32([[1, 0, t[0]], [0, 1, t[1]]]), (512, 512), flags=cv2.INTER_CUBIC)
    b[:, 300:] = 80.0  # b is flat on its right side: nothing there to support a flow
    right = make_affine([[1, 0, t[0]], [0, 1, t[1]]])
    conf = confidence_map(a, b, right)
    assert conf.shape == (512, 512) and conf.dtype == np.float32
    assert conf.min() >= 0.0 and conf.max() <= 1.0
    textured = conf[150:400, 60:250]  # the camera man and the field
    assert np.median(textured) > 0.7
    assert np.median(conf[:, 340:]) < 0.2  # only extrapolation there
    wrong = make_affine([[1, 0, t[0] + 6.0], [0, 1, t[1] - 5.0]])
    assert np.median(confidence_map(a, b, wrong)[150:400, 60:250]) < 0.2  # the flow disagrees with the images
    # mapped outside b: 0
    away = make_affine([[1, 0, 600.0], [0, 1, 0.0]])
    assert confidence_map(a, b, away).max() == 0.0
    # resized working copies give a map of the original size
    assert confidence_map(a, b, right, max_side=256).shape == (512, 512)
    summary = confidence_summary(conf)
    assert set(summary) == {"mean", "supported_share", "overlap"} and 0.0 < summary["supported_share"] < 1.0
    assert confidence_summary(None) is None


def test_match_images_reports_confidence_in_the_result_json_and_files(tmp_path):
    from reglib.outputs import save_match

    a = cv2.resize(skimage.data.astronaut(), (256, 256), interpolation=cv2.INTER_AREA)
    b = cv2.warpAffine(a, cv2.getRotationMatrix2D((128, 128), 8, 1.05), (256, 256), flags=cv2.INTER_CUBIC)
    # no dense stage, no confidence (CONTRACTS.md): the map and the JSON summary are null
    off = match_images(a, b, rng=0, options={"dense": False, "max_keypoints": 800})
    assert off.converged and off.confidence is None and off.to_dict()["confidence"] is None
    assert "confidence" not in save_match(off, tmp_path / "off", confidence=True)
    for dense in (True,):
        m = match_images(a, b, rng=0, options={"dense": dense, "max_keypoints": 800})
        assert m.confidence is not None and m.confidence.shape == (256, 256) and m.confidence.dtype == np.float32
        assert 0.0 <= m.confidence.min() and m.confidence.max() <= 1.0
        # where confidence is high the flow is right
        ys, xs = np.mgrid[0:256, 0:256]
        truth = cv2.getRotationMatrix2D((128, 128), 8, 1.05)
        true_flow = np.dstack([truth[0, 0] * xs + truth[0, 1] * ys + truth[0, 2] - xs,
                               truth[1, 0] * xs + truth[1, 1] * ys + truth[1, 2] - ys])
        err = np.linalg.norm(dense_flow(m.transform, (256, 256)) - true_flow, axis=2)
        hi = m.confidence >= 0.5
        assert hi.mean() > 0.3 and np.mean(err[hi] < 3.0) > 0.97
    body = m.to_dict()
    assert body["confidence"] == m.confidence_summary and "supported_share" in body["confidence"]
    back = ImageMatch.from_dict(json.loads(json.dumps(body)))
    assert back.confidence is None and back.to_dict()["confidence"] == body["confidence"]
    bad = dict(body, confidence={"mean": 2.0, "supported_share": 0.5})
    with pytest.raises(InputError, match="confidence"):
        ImageMatch.from_dict(bad)
    written = save_match(m, tmp_path / "out", confidence=True)
    png = cv2.imread(str(written["confidence"]), cv2.IMREAD_UNCHANGED)
    assert png.shape == (256, 256) and png.dtype == np.uint8
    assert np.abs(png / 255.0 - m.confidence).max() <= 0.5 / 255 + 1e-6
    assert "confidence" not in save_match(back, tmp_path / "out2", confidence=True)  # no map: no file


@pytest.mark.parametrize(("off", "low", "high"), [((0.0, 0.0), 0.0, 0.02), ((2.0, 0.0), 0.0, 0.02),
                                                  ((7.0, 0.0), 0.95, 1.0), ((-5.0, 6.0), 0.95, 1.0)])
def test_found_away_is_the_share_of_places_whose_match_is_beyond_away_px(make_affine, off, low, high):
    # b is camera shifted by (5, -3): an answer off by `off` has every place's own match `off` away from it
    a = skimage.data.camera().astype(np.float32)
    b = cv2.warpAffine(a, np.float32([[1, 0, 5], [0, 1, -3]]), a.shape[::-1], borderMode=cv2.BORDER_REFLECT)
    answer = make_affine([[1, 0, 5 + off[0]], [0, 1, -3 + off[1]]])
    share = found_away(a, b, answer, DenseOptions(max_side=512))
    assert low <= share <= high
    assert np.hypot(*off) > AWAY_PX or share <= 0.02
