"""The haematoxylin channel in ``match_images`` (issue 49), first try and second: the channel, when it runs, what it
keeps."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from skimage.color import hed2rgb

import reglib.matching._pipeline as pipeline
from reglib import KernelWarp, match_images
from reglib._verdict import UNSUPPORTED
from reglib.dense import OverNoMotion
from reglib.matching._inputs import read_images, run_of
from reglib.matching._second_try import haematoxylin_image, rated_better, stain_views
from reglib.matching._sparse import sift_stage, too_few

from .conftest import replaced_first_answer

SHIFT = np.array([9.0, -6.0])  # b's content is a's moved by this, px


def _nuclei(rng: np.random.Generator, n: int, shape: tuple[int, int]) -> np.ndarray:
    img = np.zeros(shape, np.float32)
    for x, y, r in zip(rng.uniform(0, shape[1], n), rng.uniform(0, shape[0], n), rng.uniform(2, 5, n), strict=True):
        cv2.circle(img, (int(x), int(y)), int(r), 1.0, -1)
    return cv2.GaussianBlur(img, (0, 0), 1.0)


def _render(h: np.ndarray, e: np.ndarray) -> np.ndarray:
    """An RGB section from haematoxylin and eosin densities (scikit-image's stain vectors)."""
    hed = np.stack([h, e, np.zeros_like(h)], -1)
    return (np.clip(hed2rgb(hed), 0, 1) * 255).astype(np.uint8)


def _sections(eosin: float) -> tuple[np.ndarray, np.ndarray]:
    """Two renderings of one section's nuclei, b's moved by SHIFT, under eosin textures that share nothing (their
    density's peak ``eosin``)."""
    rng = np.random.default_rng(1)
    size = 320
    big = _nuclei(rng, 900, (size + 40, size + 40))
    dx, dy = SHIFT.astype(int)
    h_a = big[20:20 + size, 20:20 + size]
    h_b = big[20 - dy:20 - dy + size, 20 - dx:20 - dx + size]
    e_a, e_b = (cv2.GaussianBlur(rng.random((size, size)).astype(np.float32), (0, 0), 3.0) for _ in range(2))
    return _render(1.5 * h_a, eosin * e_a / e_a.max()), _render(1.5 * h_b, eosin * e_b / e_b.max())


@pytest.fixture(scope="module")
def sections() -> tuple[np.ndarray, np.ndarray]:
    """Sections whose grey renderings SIFT still matches (a light eosin)."""
    return _sections(1.2)


@pytest.fixture(scope="module")
def eosin_heavy() -> tuple[np.ndarray, np.ndarray]:
    """Sections whose grey renderings SIFT cannot match: a dense eosin, different in a and b, hides the nuclei."""
    return _sections(2.5)


def test_haematoxylin_image_is_dark_on_the_nuclei_only() -> None:
    rng = np.random.default_rng(0)
    h = _nuclei(rng, 60, (120, 120))
    e = cv2.GaussianBlur(rng.random((120, 120)).astype(np.float32), (0, 0), 2.0)
    grey = haematoxylin_image(_render(1.5 * h, e))
    assert grey.dtype == np.uint8 and grey.shape == h.shape
    nucleus, stroma = h > 0.8, h < 0.01
    assert np.median(grey[nucleus]) < 80 < 200 < np.median(grey[stroma])
    # the eosin varies over the stroma, the channel does not follow it
    assert np.std(grey[stroma].astype(float)) < 12.0
    assert np.all(haematoxylin_image(np.full((8, 8, 3), 255, np.uint8)) == 255)  # an empty slide: white


def test_stain_views_only_for_colour_images(sections) -> None:
    a, b = sections
    run = run_of("auto", "l2e", None, 0)
    views = stain_views(read_images(a, b, None, None, run))
    assert views is not None and views.view_a.ndim == 2 and np.array_equal(views.gray_b, haematoxylin_image(b))
    assert views.img_a is not None and views.shape_a == a.shape[:2]
    assert stain_views(read_images(a[..., 0], b[..., 0], None, None, run)) is None
    grey_rgb = np.repeat(a[..., :1], 3, axis=2)
    assert stain_views(read_images(grey_rgb, b, None, None, run)) is None
    assert stain_views(read_images(a, b, None, None, run_of("auto", "l2e", {"band": 1}, 0))) is None


def test_rated_better_needs_the_margin_and_more_than_the_first() -> None:
    first = OverNoMotion(z=5.0, share=0.6, moved=20.0, neighbours=0.55, places=400.0)
    good = OverNoMotion(z=15.0, share=0.8, moved=20.0, neighbours=0.7, places=400.0)
    assert rated_better(good, first)
    assert not rated_better(dataclasses.replace(good, neighbours=0.5), first)  # not a peak: short of the margin
    assert not rated_better(good, dataclasses.replace(first, z=20.0))  # the first is rated more clearly
    assert not rated_better(good, dataclasses.replace(first, neighbours=0.75))


def _first_try_wrong(a: np.ndarray, b: np.ndarray):
    """The stages on the grey images, their answer replaced by a wrong one (a shift the other way): what an
    "unsupported" first answer hands to the second try."""
    return replaced_first_answer(a, b, "auto", dataclasses.replace(KernelWarp.identity(2), dst_mean=-SHIFT))


def test_second_try_on_the_haematoxylin_recovers_the_shift(sections) -> None:
    a, b = sections
    images, run, sparse, dense, rating = _first_try_wrong(a, b)
    got_sparse, got, converged, reason = pipeline._second_try(images, run, sparse, dense, rating)
    assert (converged, reason) == (True, None)
    pts = np.array([[80.0, 90.0], [200.0, 160.0], [150.0, 250.0]])
    assert np.abs(got.transform(pts) - pts - SHIFT).max() < 1.0
    assert "second_try" in run.timings and got_sparse is not sparse


def test_second_try_keeps_the_first_answer_when_not_rated_better(sections) -> None:
    a, b = sections
    images, run, sparse, dense, rating = _first_try_wrong(a, b)
    unbeatable = dataclasses.replace(rating, z=1e9)
    got_sparse, got, converged, reason = pipeline._second_try(images, run, sparse, dense, unbeatable)
    assert (converged, reason) == (False, UNSUPPORTED) and got is dense and got_sparse is sparse


def test_no_second_try_for_grey_images(sections) -> None:
    a, b = sections
    images, run, sparse, dense, rating = _first_try_wrong(a[..., 1], b[..., 1])
    got_sparse, got, converged, reason = pipeline._second_try(images, run, sparse, dense, rating)
    assert (converged, reason) == (False, UNSUPPORTED) and got is dense


def test_auto_answers_on_the_haematoxylin_where_sift_finds_too_little_on_grey(eosin_heavy) -> None:
    a, b = eosin_heavy
    run = run_of("auto", "l2e", None, 0)
    assert too_few(sift_stage(read_images(a, b, None, None, run), run))  # the grey renderings do not match
    m = match_images(a, b, features="auto", rng=0)
    assert (m.converged, m.reason, m.features) == (True, None, "sift")
    pts = np.array([[80.0, 90.0], [200.0, 160.0], [150.0, 250.0]])
    assert np.abs(m.transform(pts) - pts - SHIFT).max() < 1.0
    assert "haematoxylin" in m.timings_ms and "second_try" not in m.timings_ms
    grey = match_images(a[..., 1], b[..., 1], features="auto", rng=0)  # no colour: no channel to separate
    assert "haematoxylin" not in grey.timings_ms


def test_a_channel_with_too_little_falls_through_to_the_multimodal_features() -> None:
    """Colour sections with no haematoxylin at all (eosin only, a's and b's unrelated): the grey images do not
    match, the channel is blank, its SIFT finds nothing, and the multimodal features answer."""
    rng = np.random.default_rng(2)
    blank = np.zeros((256, 256), np.float32)
    a, b = (_render(blank, 1.5 * cv2.GaussianBlur(rng.random((256, 256)).astype(np.float32), (0, 0), 2.0) / 0.6)
            for _ in range(2))
    run = run_of("auto", "l2e", None, 0)
    images = read_images(a, b, None, None, run)
    assert too_few(sift_stage(images, run))
    sparse, _, _, stain_sift = pipeline._try(images, run)
    assert stain_sift is not None and too_few(stain_sift)
    assert sparse.features == "multimodal" and "haematoxylin" in run.timings
