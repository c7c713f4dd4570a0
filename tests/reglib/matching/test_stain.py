"""match_images across stains: two colour-deconvolution renderings of scikit-image's immunohistochemistry
section, the second with the fine structure of another section and a known smooth warp."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import skimage.data
from skimage.color import hed2rgb, rgb2hed

from reglib import ImageMatch, InputError, match_images


def _forward(p: np.ndarray) -> np.ndarray:
    """The true map a -> b: a shift (10, -6) px and a bend of 8 / 6 px amplitude across the image."""
    return p + np.c_[8 * np.sin(2 * np.pi * p[:, 1] / 512) + 10, 6 * np.cos(2 * np.pi * p[:, 0] / 512) - 6]


@pytest.fixture(scope="module")
def stain_pair() -> tuple[np.ndarray, np.ndarray]:
    hed = rgb2hed(skimage.data.immunohistochemistry())
    h, d = np.maximum(hed[..., 0], 0), np.maximum(hed[..., 2], 0)
    eosin = cv2.GaussianBlur(h + d, (0, 0), 3.0) * 1.5  # a: haematoxylin and an eosin-like counterstain
    a = (np.clip(hed2rgb(np.stack([h, eosin, np.zeros_like(h)], -1)), 0, 1) * 255).astype(np.uint8)
    # b: weak haematoxylin and DAB, the cells a few px elsewhere (another section)
    rb = np.clip(hed2rgb(np.stack([0.25 * h, 0.5 * cv2.GaussianBlur(h + d, (0, 0), 6.0), 1.2 * d], -1)), 0, 1)
    rng = np.random.default_rng(3)
    jitter = [cv2.GaussianBlur(rng.normal(0, 1, h.shape), (0, 0), 5.0) for _ in range(2)]
    jitter = [(j * 2.5 / j.std()).astype(np.float32) for j in jitter]
    ys, xs = np.mgrid[0:512, 0:512].astype(np.float32)
    rb = cv2.remap(rb.astype(np.float32), xs + jitter[0], ys + jitter[1], cv2.INTER_LINEAR,
                   borderMode=cv2.BORDER_REFLECT)
    q = np.c_[xs.ravel(), ys.ravel()].astype(float)
    p = q.copy()
    for _ in range(30):  # T^-1 by fixed-point iteration (the bend's slope is below 0.1)
        p = p - (_forward(p) - q)
    m = p.astype(np.float32).reshape(512, 512, 2)
    b = cv2.remap((rb * 255).astype(np.uint8), m[..., 0], m[..., 1], cv2.INTER_LINEAR)
    return a, b


# SIFT alone finds 10 inliers here (too few to trust): the dense stage takes it from 3.8 px to about 1 px; the
# multimodal fit is about 1.5 px already, and the dense stage must keep that (not make it worse than 0.25 px more)
@pytest.mark.parametrize("features, margin", [("sift", 0.0), ("multimodal", 0.25)])
def test_the_dense_stage_is_kept_across_stains_and_improves_the_answer(stain_pair, features, margin):
    a, b = stain_pair
    pts = np.random.default_rng(0).uniform(60, 450, (80, 2))
    sparse = match_images(a, b, features=features, rng=0, options={"dense": False})
    m = match_images(a, b, features=features, rng=0)
    err = float(np.median(np.linalg.norm(m.transform(pts) - _forward(pts), axis=1)))
    err_sparse = float(np.median(np.linalg.norm(sparse.transform(pts) - _forward(pts), axis=1)))
    assert sparse.dense == "not_run" and sparse.confidence_summary is None
    assert m.confidence_summary["dense"] == "kept" and m.n_dense > 100
    assert err < 2.0 and err < err_sparse + margin  # no motion is 12 px off
    assert m.converged and m.reason is None


def test_the_dense_outcome_travels_in_the_match_json(stain_pair):
    a, b = stain_pair
    body = json.loads(json.dumps(match_images(a, b, rng=0).to_dict()))
    outcome = body["confidence"]["dense"]
    assert outcome == "kept"
    back = ImageMatch.from_dict(body)
    assert back.dense == outcome and back.confidence_summary["dense"] == outcome
    old = {**body, "confidence": {k: v for k, v in body["confidence"].items() if k != "dense"}}
    assert ImageMatch.from_dict(old).dense == "kept"  # written before the key: a dense stage whose result was used
    assert ImageMatch.from_dict({**body, "confidence": None}).dense == "not_run"
    with pytest.raises(InputError, match="confidence.dense` must be one of"):
        ImageMatch.from_dict({**body, "confidence": {**body["confidence"], "dense": "maybe"}})
