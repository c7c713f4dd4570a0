"""ImageMatch / FilterResult JSON read-back: claims that do not fit their data are named InputErrors."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import FilterResult, ImageMatch, InputError, filter_matches, match_images


@pytest.fixture(scope="module")
def match_dict() -> dict:
    a = skimage.data.camera()[100:356, 100:356]
    b = cv2.warpAffine(a, np.float32([[1, 0, 3], [0, 1, -2]]), (256, 256))
    body = match_images(a, b, rng=0, options={"dense": False}).to_dict()
    assert body["n_matches"] > 10
    return json.loads(json.dumps(body))


@pytest.mark.parametrize("key, value, words", [
    ("n_matches", 10 ** 20, "scores` must have shape"),   # no mask of 1e20 entries is made first
    ("n_matches", 3, "scores` must have shape"),
    ("shape_a", [10 ** 20, 5], "shape_a` must be numbers"),  # over int64: named, not OverflowError
    ("shape_b", 10 ** 20, "shape_b` must be numbers"),
])
def test_image_match_json_with_impossible_sizes_is_an_input_error(match_dict, key, value, words):
    assert ImageMatch.from_dict(match_dict).n_matches == match_dict["n_matches"]
    bad = {**match_dict, key: value}
    with pytest.raises(InputError, match=words):
        ImageMatch.from_dict(bad)


def test_filter_result_json_with_an_impossible_count_is_an_input_error():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 100, (40, 2))
    body = json.loads(json.dumps(filter_matches(src, src + 1.0, rng=0).to_dict()))
    assert FilterResult.from_dict(body).n_inliers == body["n_inliers"]
    with pytest.raises(InputError, match="scores` must have shape"):
        FilterResult.from_dict({**body, "n_matches": 10 ** 20})
