"""``match_images`` on TIFFs over ``max_pixels``: read at a working size, the answer in full-resolution pixels."""
from __future__ import annotations

import numpy as np
import pytest

from reglib import match_images
from reglib.errors import ImageTooLarge, InputError
from reglib.io import encode_png

# a 3000 x 3000 pair over this limit is read reduced by 4 (750 px), within max_side
_OPTIONS = {"max_pixels": 1_000_000, "max_side": 800}


@pytest.fixture(scope="module")
def large_match(large_pair):
    return match_images(large_pair.path_a, large_pair.path_b, rng=0, options=_OPTIONS)


def test_a_large_tiff_pair_is_matched_in_full_resolution_pixels(large_pair, large_match):
    m = large_match
    assert m.converged and m.shape_a == (3000, 3000) and m.shape_b == (3000, 3000)
    pts = np.random.default_rng(0).uniform(100, 2900, (400, 2))
    err = np.linalg.norm(m.transform(pts) - large_pair.true_map(pts), axis=1)
    assert np.median(err) < 1.0  # full-resolution pixels: 0.25 px at the working size
    # the inliers are matches in full-resolution pixels: the true map carries them
    inl = m.inliers
    assert np.median(np.linalg.norm(large_pair.true_map(m.src[inl]) - m.dst[inl], axis=1)) < 2.0
    assert m.keypoints_a.max() > 2000  # keypoints span the full image
    assert m.confidence is None and m.confidence_summary is not None
    assert m.to_dict()["shape_a"] == [3000, 3000]


def test_the_same_pair_decoded_whole_agrees(large_pair, large_match):
    """Within the limit the pair is read whole (the pipeline resizes it itself): the two answers agree."""
    whole = match_images(large_pair.path_a, large_pair.path_b, rng=0, options={"max_side": 750})
    pts = np.random.default_rng(1).uniform(100, 2900, (200, 2))
    assert np.median(np.linalg.norm(whole.transform(pts) - large_match.transform(pts), axis=1)) < 1.0


def test_masks_and_other_formats_over_the_limit_are_refused(large_pair, tmp_path):
    with pytest.raises(InputError, match="masks"):
        match_images(large_pair.path_a, large_pair.path_b, options=_OPTIONS, mask_a=np.ones((3000, 3000), bool))
    (tmp_path / "a.png").write_bytes(encode_png(large_pair.image_a[:1200, :1200]))
    with pytest.raises(ImageTooLarge, match="only a TIFF"):
        match_images(tmp_path / "a.png", large_pair.path_b, options=_OPTIONS)
