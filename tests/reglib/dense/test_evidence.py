"""Tests of the dense stage's similarity evidence (reglib.dense._evidence: local_similarity, evidence_z,
evidence_over_no_motion) and of the guard's outcome it decides, with known shifts of scikit-image samples."""
from __future__ import annotations

import cv2
import numpy as np
import skimage.data

from reglib import KernelWarp
from reglib._transforms import LinearPart
from reglib.dense import (
    DENSE_OUTCOMES,
    EVIDENCE_Z,
    DenseOptions,
    evidence_over_no_motion,
    rate_over_no_motion,
)
from reglib.dense._evidence import (
    MIN_NEIGHBOUR_SHARE,
    MIN_REGION_SHARE,
    MIN_SHARE,
    MOVE_PX,
    NEIGHBOUR_PX,
    NONE_MARGIN,
    _neighbour_shifts,
    _patches_a,
    _similarities,
    evidence_z,
    local_similarity,
)
from reglib.dense._guarding import guard
from reglib.dense._refine import working_frames
from reglib.dense._result import DenseFit


def _shift(dx: float, dy: float) -> KernelWarp:
    return KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.zeros(2), dst_scale=1.0,
                      linear=LinearPart(kind="affine", matrix=np.array([[1.0, 0, dx], [0, 1.0, dy]])), beta=1.0,
                      centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))


def _field(img: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(img, np.float32)[:, :, None]


def _camera_pair(dx: int = 6, dy: int = -4) -> tuple[np.ndarray, np.ndarray]:
    """a and b = a moved by (dx, dy) px (b(x + dx, y + dy) = a(x, y)): the true transform is a shift by (dx, dy)."""
    a = skimage.data.camera()[64:320, 64:320].astype(np.float32)
    b = cv2.warpAffine(a, np.float32([[1, 0, dx], [0, 1, dy]]), a.shape[::-1], borderMode=cv2.BORDER_REFLECT)
    return a, b


def test_local_similarity_is_highest_at_the_true_shift_and_nan_outside():
    a, b = _camera_pair()
    pts = np.array([[128.0, 128.0], [64.0, 100.0], [2.0, 2.0], [250.0, 128.0]])
    at_truth = local_similarity(_field(a), _field(b), _shift(6, -4), pts, 8)
    off = local_similarity(_field(a), _field(b), _shift(0, 0), pts, 8)
    assert at_truth.shape == (4,)
    np.testing.assert_allclose(at_truth[:2], 1.0, atol=1e-3)  # the same patch: NCC 1
    assert np.all(off[:2] < 0.9)
    assert np.isnan(at_truth[2])  # the patch leaves a
    assert np.isnan(at_truth[3])  # mapped beyond b's right border
    assert local_similarity(_field(a), _field(b), _shift(6, -4), np.zeros((0, 2)), 8).shape == (0,)


def test_evidence_z_ranks_the_true_shift_over_a_wrong_one_and_over_no_motion():
    a, b = _camera_pair()
    fa, fb = _field(a), _field(b)
    assert evidence_z(fa, fb, _shift(6, -4), _shift(0, 0), 16) > 5.0
    assert evidence_z(fa, fb, _shift(0, 0), _shift(6, -4), 16) < -5.0
    assert evidence_z(fa, fb, _shift(6, -4), _shift(6, -4), 16) == 0.0  # nothing differs: no evidence
    opts = DenseOptions(max_side=256)
    assert evidence_over_no_motion(a, b, _shift(6, -4), opts) >= EVIDENCE_Z
    # an answer 9 px off where b is a itself: the images rate it worse than no motion
    assert evidence_over_no_motion(a, a, _shift(9, 0), opts) <= -EVIDENCE_Z


def _fine_texture(seed: int = 0, size: int = 256) -> np.ndarray:
    """A texture whose similarity vanishes a few px off (noise blurred by 1 px): any two wrong motions are about
    as dissimilar as each other."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(0, 1, (size, size)), (0, 0), 1.0)
    return ((img - img.min()) / np.ptp(img) * 255).astype(np.float32)


def test_a_motion_worse_than_no_motion_falls_short_of_the_margin_and_the_true_one_does_not():
    # b: a moved by (6, -4) px and rendered otherwise (gamma, blur); no motion is 7.2 px off, the forced bad
    # motion (-6, 4) 14.4 px: at both the patches are about as dissimilar, so the sign test alone cannot rate the
    # bad one worse than no motion (z > -EVIDENCE_Z), yet it is not rated over it either
    a = _fine_texture()
    b = cv2.warpAffine(a, np.float32([[1, 0, 6], [0, 1, -4]]), a.shape[::-1], borderMode=cv2.BORDER_REFLECT)
    b = cv2.GaussianBlur((b / 255.0) ** 1.5 * 255.0, (0, 0), 0.7).astype(np.float32)
    opts = DenseOptions(max_side=256)
    good = rate_over_no_motion(a, b, _shift(6, -4), opts)
    assert good.z >= NONE_MARGIN and good.moved > MOVE_PX and not good.short_of_margin
    bad = rate_over_no_motion(a, b, _shift(-6, 4), opts)
    assert -EVIDENCE_Z < bad.z < NONE_MARGIN  # the old rule alone (z <= -EVIDENCE_Z) let it through
    assert bad.moved > MOVE_PX and bad.short_of_margin
    assert evidence_over_no_motion(a, b, _shift(-6, 4), opts) == bad.z


def test_an_answer_right_on_a_strip_alone_falls_short_of_the_share_on_a_large_image():
    # b: a moved by (6, -4) px on the left 15 % and by (-6, 4) px on the rest. The answer (6, -4) is right on the
    # strip and 14.4 px off elsewhere, where no motion is 7.2 px off: worse than no motion over most of the image.
    # It wins every place on the strip and about half the others; over ~400 places that is a clear z, not a share
    a = _fine_texture(2, 512)
    h, w = a.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    left = cv2.GaussianBlur((xs < 0.15 * w).astype(np.float32), (0, 0), 3.0)
    dx, dy = 6 * left - 6 * (1 - left), -4 * left + 4 * (1 - left)
    b = cv2.remap(a, xs - dx, ys - dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    rating = rate_over_no_motion(a, b, _shift(6, -4), DenseOptions(max_side=512))
    assert rating.z >= NONE_MARGIN and rating.share < MIN_SHARE and rating.short_of_margin
    truth = rate_over_no_motion(a, b, _shift(-6, 4), DenseOptions(max_side=512))  # right on 85 %
    assert truth.share >= MIN_SHARE and not truth.short_of_margin


def test_an_answer_close_to_no_motion_is_not_held_to_the_margin():
    # b is a moved by half a pixel: the true answer moves too little for the margin to apply (where the images
    # barely differ between the two, the sign test is a coin toss; only a clear loss, z <= -EVIDENCE_Z, counts)
    a = _fine_texture(1)
    b = cv2.warpAffine(a, np.float32([[1, 0, 0.5], [0, 1, 0]]), a.shape[::-1], borderMode=cv2.BORDER_REFLECT)
    near = rate_over_no_motion(a, b, _shift(0.5, 0), DenseOptions(max_side=256))
    assert near.moved <= MOVE_PX and not near.short_of_margin
    far = rate_over_no_motion(a, b, _shift(0.5 + 2 * MOVE_PX, 0), DenseOptions(max_side=256))
    assert far.moved > MOVE_PX and far.short_of_margin  # the same images: a motion that far is held to it


def _two_scale(seed: int, size: int) -> np.ndarray:
    """Coarse blobs (noise blurred by 8 px) and fine texture (blurred by 1 px): a motion a few px off keeps the
    blobs' similarity and loses the texture's."""
    rng = np.random.default_rng(seed)
    coarse = cv2.GaussianBlur(rng.normal(0, 1, (size, size)), (0, 0), 8.0)
    fine = cv2.GaussianBlur(rng.normal(0, 1, (size, size)), (0, 0), 1.0)
    return (coarse / coarse.std() + 0.7 * fine / fine.std()).astype(np.float32)


def test_an_answer_off_everywhere_yet_better_than_no_motion_falls_short_of_its_neighbours():
    # b: a moved by (12, -8) px, with noise. An answer 5-6 px off everywhere still overlaps the blobs, so the images
    # rate it clearly over no motion (14 px off) by z and share alike; but it is no peak of the similarity: moved by
    # NEIGHBOUR_PX it is about as similar, where the true answer is more similar than all its neighbours
    for seed in range(2):
        a = _two_scale(seed, 640)
        b = cv2.warpAffine(a, np.float32([[1, 0, 12], [0, 1, -8]]), a.shape[::-1], borderMode=cv2.BORDER_REFLECT)
        b = b + np.random.default_rng(seed + 10).normal(0, 0.8, b.shape).astype(np.float32)
        opts = DenseOptions(max_side=640)
        truth = rate_over_no_motion(a, b, _shift(12, -8), opts)
        assert truth.neighbours > 0.95 and not truth.below_neighbours and not truth.short_of_margin
        for off in (_shift(18, -8), _shift(15, -4)):
            rating = rate_over_no_motion(a, b, off, opts)
            assert rating.z >= NONE_MARGIN and rating.share >= MIN_SHARE and rating.moved > MOVE_PX
            assert rating.neighbours < MIN_NEIGHBOUR_SHARE and rating.below_neighbours and rating.short_of_margin
            assert rating.places > 500
        # on a quarter of it (a sixth of the places) the same share is not clearly short: too few places to tell
        small = rate_over_no_motion(a[:256, :256], b[:256, :256], _shift(18, -8), DenseOptions(max_side=256))
        assert small.neighbours < MIN_NEIGHBOUR_SHARE and not small.below_neighbours


def test_an_answer_that_misses_a_local_bump_is_no_peak_in_that_region_alone():
    # b: a moved by (12, -8) px everywhere, and by 12 px more along x in a smooth bump over the top-left ninth. The
    # answer (12, -8) is right on eight ninths of a: over the whole image it is a clear peak of the similarity, but in
    # the bump's region it is 12 px off and about as similar as its neighbours. The truth has no weak region
    for seed in range(2):
        a = _fine_texture(seed, 640)
        h, w = a.shape
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
        bump = cv2.GaussianBlur(((xs < w / 3) & (ys < h / 3)).astype(np.float32), (0, 0), 6.0)
        dx, dy = 12 + 12 * bump, np.full_like(bump, -8.0)
        b = cv2.remap(a, xs - dx, ys - dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)  # approximately
        b = b + np.random.default_rng(seed + 10).normal(0, 0.5, b.shape).astype(np.float32)
        opts = DenseOptions(max_side=640)
        missed = rate_over_no_motion(a, b, _shift(12, -8), opts)
        assert not missed.short_of_margin and missed.neighbours > MIN_NEIGHBOUR_SHARE + 0.1  # the whole image backs it
        assert missed.weakest < MIN_REGION_SHARE and missed.weakest_z >= EVIDENCE_Z and missed.weak_region
        plain = cv2.warpAffine(a, np.float32([[1, 0, 12], [0, 1, -8]]), a.shape[::-1], borderMode=cv2.BORDER_REFLECT)
        truth = rate_over_no_motion(a, plain, _shift(12, -8), opts)
        assert truth.weakest > 0.9 and not truth.weak_region
        # an answer off by (4, 4) px everywhere is no peak anywhere (two of its neighbours are nearer the truth):
        # no region is weaker than the rest, so the regions do not count it; the whole image's test does
        off = rate_over_no_motion(a, plain, _shift(16, -4), opts)
        assert off.weakest < MIN_REGION_SHARE and off.weakest_z < EVIDENCE_Z and not off.weak_region
        assert off.below_neighbours and off.short_of_margin


def test_similarities_at_shifts_are_the_local_similarity_of_the_moved_answer():
    a, b = _camera_pair()
    fa, fb = _field(a), _field(b)
    pts = np.array([[128.0, 128.0], [64.0, 100.0], [200.0, 60.0], [9.0, 128.0]])
    shifts = _neighbour_shifts(NEIGHBOUR_PX)
    sims = _similarities(fa, fb, _shift(6, -4), pts, 8, shifts)
    assert sims.shape == (5, 4)
    np.testing.assert_array_equal(sims[0], local_similarity(fa, fb, _shift(6, -4), pts, 8))
    for (dx, dy), row in zip(shifts[1:], sims[1:], strict=True):
        # p -> truth(p + shift): b resampled at p + (dx + 6, dy - 4), as the shift moved by (dx, dy)
        np.testing.assert_allclose(row[:3], local_similarity(fa, fb, _shift(6 + dx, -4 + dy), pts[:3], 8), atol=1e-5)
    assert np.isnan(sims[2, 3])  # moved by -NEIGHBOUR_PX in x, the patch at x = 9 leaves a
    assert np.all(sims[0, :3] > sims[1:, :3])  # the true answer is a peak


def test_a_patches_computed_once_give_the_same_similarities_for_every_transform():
    # a's side is shared by the transforms rated at the same points: the numbers are those computed alone
    a, b = _camera_pair()
    fa = np.ascontiguousarray(np.stack([a, 255.0 - a, a * a / 255.0], axis=2), np.float32)
    fb = np.ascontiguousarray(np.stack([b, 255.0 - b, b * b / 255.0], axis=2), np.float32)
    pts = np.array([[128.0, 128.0], [64.0, 100.0], [200.0, 60.0], [9.0, 128.0], [250.0, 250.0]])
    patches = _patches_a(fa, pts, 8)
    for t in (_shift(6, -4), _shift(0, 0), _shift(-3, 11)):
        alone = _similarities(fa, fb, t, pts, 8, _neighbour_shifts(NEIGHBOUR_PX))
        shared = _similarities(fa, fb, t, pts, 8, _neighbour_shifts(NEIGHBOUR_PX), patches)
        assert alone.tobytes() == shared.tobytes()
        assert local_similarity(fa, fb, t, pts, 8, patches).tobytes() == local_similarity(fa, fb, t, pts, 8).tobytes()
    assert np.isfinite(shared[0, :3]).all() and np.isnan(shared[0, 3])


def test_guard_keeps_a_dense_estimate_the_check_cannot_see_when_the_similarity_favours_it():
    # b: a moved by (6, -4) px and blurred hard (another rendering of the same structure: the check's distinct
    # peaks are gone, the similarity at the true place stays higher than at f0, 6 px off)
    a, b = _camera_pair()
    b = cv2.GaussianBlur(b, (0, 0), 6.0)
    size = a.shape[0]
    f0, truth = _shift(0, 0), _shift(6, -4)
    grid = np.mgrid[8:size - 8:8, 8:size - 8:8].reshape(2, -1).T[:, ::-1].astype(float)
    opts = DenseOptions(max_side=size)
    res = guard(working_frames(a, b, opts), f0, DenseFit(transform=truth, converged=True, src=grid, dst=truth(grid)),
                opts, np.random.default_rng(0), rounds=1)
    assert res.outcome == "kept" and not res.kept_first and res.transform is truth
    # the same guard with the two swapped: the wrong dense estimate is refused, f0 (now the true one) stays
    res = guard(working_frames(a, b, opts), truth, DenseFit(transform=f0, converged=True, src=grid, dst=grid),
                opts, np.random.default_rng(0), rounds=1)
    assert res.outcome == "no_support" and res.kept_first and res.transform is truth
    assert set(DENSE_OUTCOMES) == {"kept", "sparse_better", "no_support", "no_matches", "not_run"}
