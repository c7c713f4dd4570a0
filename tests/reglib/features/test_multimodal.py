"""Tests of the modality-robust features: phase congruency, MIM descriptors, refinement, structure."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.distance import cdist
from skimage import data

from reglib import filter_matches
from reglib.errors import InputError
from reglib.features.multimodal import (
    N_ROTATIONS,
    align_rigid,
    detect_multimodal,
    match_multimodal,
    normalize_intensity,
    refine_matches,
    structure_image,
)
from reglib.features.phase import log_gabor_bank, phase_congruency

CAMERA = data.camera()  # (512, 512) uint8
H, W = CAMERA.shape


def _remap(img: np.ndarray) -> np.ndarray:
    """A non-monotonic change of 'sensor': inverted, gamma 0.5, plus a bump in the mid-greys."""
    u = img.astype(np.float64) / 255.0
    v = 1.0 - np.sqrt(u) + 0.25 * np.exp(-((u - 0.5) / 0.1) ** 2)
    return np.clip(v * 200.0, 0, 255).astype(np.uint8)


def _similarity(angle: float, scale: float, shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    m = cv2.getRotationMatrix2D((W / 2 - 0.5, H / 2 - 0.5), angle, scale)
    m[:, 2] += shift
    return m


def _apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ m[:, :2].T + m[:, 2]


def _pair(angle: float, scale: float, shift: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    m = _similarity(angle, scale, shift)
    b = cv2.warpAffine(CAMERA, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return _remap(b), m


@pytest.fixture(scope="module")
def feat_a():
    return detect_multimodal(CAMERA)


# ----------------------------------------------------------------------------- normalize_intensity

def test_normalize_percentile_stretch_ignores_hot_pixels():
    rng = np.random.default_rng(0)
    img = rng.integers(1000, 2000, (64, 64)).astype(np.uint16)
    img[0, :3] = 65535  # three hot pixels
    out = normalize_intensity(img)
    assert out.dtype == np.float32 and out.shape == img.shape
    assert 0.0 <= out.min() and out.max() <= 1.0
    assert np.median(out) == pytest.approx(0.5, abs=0.05)  # content is not squeezed to the bottom


def test_normalize_float_colour_and_constant():
    rgb = np.zeros((8, 8, 3), np.float64)
    rgb[:, 4:] = [10.0, 20.0, 30.0]
    out = normalize_intensity(rgb, low=0, high=100)
    assert out.shape == (8, 8) and out[:, :4].max() == 0.0 and out[:, 4:].min() == 1.0
    assert not normalize_intensity(np.full((5, 5), 7.0)).any()
    nan = np.full((4, 4), np.nan)
    assert np.all(np.isfinite(normalize_intensity(nan)))


# ----------------------------------------------------------------------------- phase congruency

def test_log_gabor_bank_is_one_sided_and_cached():
    bank = log_gabor_bank((64, 80))
    assert bank.filters.shape == (24, 64, 80) and bank.filters[:, 0, 0].max() == 0.0
    assert log_gabor_bank((64, 80)) is bank
    # orientation 0 passes +x frequencies only: the response to a real image is analytic-like
    fx = np.fft.fftfreq(80)
    assert bank.filters[0][0, fx < 0].max() == 0.0 and bank.filters[0][0, fx > 0].max() > 0.1


def test_phase_congruency_is_contrast_invariant_and_finds_a_step():
    img = np.zeros((64, 64))
    img[:, 32:] = 1.0
    pc = phase_congruency(img)
    pc_low = phase_congruency(0.2 + 0.3 * img)
    assert pc.edge.shape == (64, 64) and 0.0 <= pc.edge.min() and pc.edge.max() <= 1.0
    col = int(np.argmax(pc.edge[32]))
    assert col in (31, 32)
    assert pc.edge[32, col] > 0.3 and pc.edge[32, 10] < 0.05
    np.testing.assert_allclose(pc_low.edge[:, 16:48], pc.edge[:, 16:48], atol=0.05)


def test_phase_congruency_of_an_image_thinner_than_its_padding():
    # 12 rows: too few to reflect 16 px of padding, so none is added; 362 columns are padded to an FFT
    # size (375), and the maps were then cut from the wrong offset (empty)
    img = np.zeros((12, 362))
    img[:, 181:] = 1.0
    pc = phase_congruency(img)
    assert pc.edge.shape == (12, 362) and pc.corner.shape == (12, 362)
    assert int(np.argmax(pc.edge[6, 100:260])) + 100 in (180, 181)


# ----------------------------------------------------------------------------- detect_multimodal

def test_detect_shapes_and_coordinates_in_original_pixels(feat_a):
    f = feat_a
    assert f.points.dtype == np.float64 and f.points.shape == (1500, 2)
    assert f.descriptors.dtype == np.float32 and f.descriptors.shape == (1500, N_ROTATIONS * 216)
    assert f.sizes.shape == f.angles.shape == (1500,)
    blocks = f.descriptors.reshape(1500, N_ROTATIONS, 216)
    np.testing.assert_allclose(np.linalg.norm(blocks, axis=2), 1.0, atol=1e-5)
    big = cv2.resize(CAMERA, (1024, 768), interpolation=cv2.INTER_CUBIC)  # anisotropic, > max_side
    g = detect_multimodal(big, max_keypoints=200)
    assert g.points[:, 0].max() > 900 and g.points[:, 1].max() > 650
    assert g.points.min() >= 0 and g.points[:, 0].max() < 1024 and g.points[:, 1].max() < 768


def test_detect_is_deterministic_and_dtype_robust(feat_a):
    again = detect_multimodal(CAMERA)
    np.testing.assert_array_equal(again.points, feat_a.points)
    np.testing.assert_array_equal(again.descriptors, feat_a.descriptors)
    kw = {"max_keypoints": 300, "n_levels": 1}
    f8 = detect_multimodal(CAMERA, **kw)
    f16 = detect_multimodal(CAMERA.astype(np.uint16) * 256 + 3, **kw)
    f32 = detect_multimodal(CAMERA.astype(np.float32) / 255.0 * 4000.0 - 10.0, **kw)
    for f in (f16, f32):
        assert len(f.points) == len(f8.points)
        nearest = cdist(f.points, f8.points).min(axis=1)
        assert np.mean(nearest < 0.5) > 0.9


def test_detect_mask_upright_and_empty():
    mask = np.zeros((H, W), bool)
    mask[:, :256] = True
    f = detect_multimodal(CAMERA, mask=mask, max_keypoints=200, rotation_invariant=False, n_levels=1)
    assert len(f.points) > 50 and f.points[:, 0].max() < 257
    assert f.descriptors.shape == (len(f.points), 216)
    empty = detect_multimodal(CAMERA[:10, :10])
    assert empty.points.shape == (0, 2) and empty.descriptors.shape == (0, N_ROTATIONS * 216)
    none = detect_multimodal(CAMERA, mask=np.zeros((H, W), bool))
    assert none.points.shape == (0, 2)
    flat = detect_multimodal(np.full((64, 64), 9, np.uint8))
    assert flat.points.shape == (0, 2)


@pytest.mark.parametrize("kwargs, match", [
    ({"image": np.zeros((4, 4, 2))}, "image"),
    ({"image": np.zeros((32, 32), complex)}, "image"),
    ({"image": CAMERA, "mask": np.ones((5, 5))}, "mask"),
    ({"image": CAMERA, "max_keypoints": 0}, "max_keypoints"),
    ({"image": CAMERA, "n_levels": 0}, "n_levels"),
    ({"image": CAMERA, "edge_share": 2.0}, "edge_share"),
])
def test_detect_errors(kwargs, match):
    with pytest.raises(InputError, match=match):
        detect_multimodal(**kwargs)


# ----------------------------------------------------------------------------- matching, known transforms

@pytest.mark.parametrize("angle, scale, shift", [
    (0.0, 1.0, (12.0, -7.0)),   # intensity remap only (and a shift)
    (-33.0, 1.25, (0.0, 0.0)),  # rotation between hypotheses and zoom, remapped
    (90.0, 0.85, (5.0, 5.0)),   # a quarter turn and shrink, remapped
])
def test_matches_are_right_under_remap_rotation_and_scale(feat_a, angle, scale, shift):
    b, m = _pair(angle, scale, shift)
    fb = detect_multimodal(b)
    ia, ib = match_multimodal(feat_a.descriptors, fb.descriptors)
    assert len(ia) >= 40
    err = np.linalg.norm(_apply(m, feat_a.points[ia]) - fb.points[ib], axis=1)
    assert np.mean(err < 3.0) > 0.6
    # through the estimator: the recovered map is right where the image has content
    res = filter_matches(feat_a.points[ia], fb.points[ib], options={"n_centers": 0, "max_centers": 0}, rng=0)
    grid = np.stack(np.meshgrid(np.linspace(100, 400, 7), np.linspace(100, 400, 7)), -1).reshape(-1, 2)
    assert np.abs(res.transform(grid) - _apply(m, grid)).max() < 2.0


def test_sift_fails_where_multimodal_works(feat_a):
    """The reason for the module: SIFT's descriptors do not survive the remap."""
    from reglib.features.sift import detect_sift, match_descriptors

    b, m = _pair(0.0, 1.0, (12.0, -7.0))
    sa, sb = detect_sift(CAMERA), detect_sift(b)
    ia, ib = match_descriptors(sa.descriptors, sb.descriptors, ratio=0.8)
    err = np.linalg.norm(_apply(m, sa.points[ia]) - sb.points[ib], axis=1)
    assert np.count_nonzero(err < 3.0) < 40


def test_match_multimodal_empty_errors_and_ratio():
    d = np.eye(24, dtype=np.float32)[:5]
    ia, ib = match_multimodal(d[:0], d, n_rotations=1)
    assert ia.shape == ib.shape == (0,) and ia.dtype == np.intp
    ia, ib = match_multimodal(d, d, n_rotations=1, ratio=1.0, mutual=False)
    np.testing.assert_array_equal(ia, ib)
    with pytest.raises(InputError, match="n_rotations"):
        match_multimodal(d, d, n_rotations=5)
    with pytest.raises(InputError, match="desc_a"):
        match_multimodal(d, d[:, :12], n_rotations=1)
    with pytest.raises(InputError, match="ratio"):
        match_multimodal(d, d, n_rotations=1, ratio=0.0)


# ----------------------------------------------------------------------------- refine_matches

def test_refine_moves_near_misses_onto_the_truth():
    b, m = _pair(0.0, 1.0, (6.0, 3.0))
    rng = np.random.default_rng(1)
    src = rng.uniform(80, 430, (60, 2))
    truth = _apply(m, src)
    dst = truth + rng.uniform(-5, 5, truth.shape)
    new, score = refine_matches(CAMERA, b, src, dst)
    assert new.shape == (60, 2) and score.shape == (60,)
    before = np.linalg.norm(dst - truth, axis=1)
    after = np.linalg.norm(new - truth, axis=1)
    assert np.median(after) < 1.0 < np.median(before)
    empty, s0 = refine_matches(CAMERA, b, np.zeros((0, 2)), np.zeros((0, 2)))
    assert empty.shape == (0, 2) and s0.shape == (0,)
    with pytest.raises(InputError, match="src"):
        refine_matches(CAMERA, b, src, dst[:3])


# ----------------------------------------------------------------------------- structure_image

def test_structure_image_is_unit_scaled_and_contrast_invariant():
    img = CAMERA.astype(np.float64)
    f = structure_image(img)
    g = structure_image(3.0 * img + 100.0)
    assert f.shape == (H, W, 9) and f.dtype == np.float32
    norm = np.linalg.norm(f, axis=2)
    assert norm.max() <= 1.0 + 1e-5 and np.median(norm) > 0.5
    np.testing.assert_allclose(f, g, atol=1e-4)
    with pytest.raises(InputError, match="image"):
        structure_image(np.zeros((2, 2, 2, 2)))


def test_structure_correlation_locates_a_remapped_patch():
    """Zero-mean NCC of two structure fields peaks at the true shift across the remap."""
    b, _ = _pair(0.0, 1.0, (9.0, -4.0))
    fa, fb = structure_image(CAMERA), structure_image(b)
    tpl = fa[200:260, 200:260]
    win = fb[180:290, 190:300]
    score = sum(cv2.matchTemplate(np.ascontiguousarray(win[:, :, c:c + 3]),
                                  np.ascontiguousarray(tpl[:, :, c:c + 3]), cv2.TM_CCOEFF_NORMED)
                for c in range(0, 9, 3))
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    assert (190 + ix - 200, 180 + iy - 200) == (9, -4)


# ----------------------------------------------------------------------------- align_rigid

def _pseudo_colour_pet(angle: float, shift: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A 'PET' of the camera image: moved rigidly, blurred hard, shown in the JET colour scale."""
    m = _similarity(angle, 1.0, shift)
    moved = cv2.warpAffine(CAMERA, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    blurred = cv2.GaussianBlur(_remap(moved), (0, 0), 6.0)
    return cv2.cvtColor(cv2.applyColorMap(blurred, cv2.COLORMAP_JET), cv2.COLOR_BGR2RGB), m


def test_align_rigid_recovers_a_rigid_map_across_a_pseudo_colour_scale():
    b, m = _pseudo_colour_pet(7.0, (-20.0, 14.0))
    matrix, nmi, nmi_true, _ = align_rigid(CAMERA, b, compare=lambda p: _apply(m, p))
    assert matrix.shape == (2, 3)
    grid = np.stack(np.meshgrid(np.linspace(60, 450, 6), np.linspace(60, 450, 6)), -1).reshape(-1, 2)
    assert np.abs(grid @ matrix[:, :2].T + matrix[:, 2] - _apply(m, grid)).max() < 3.0
    assert 1.0 < nmi < 2.0 and nmi_true == pytest.approx(nmi, abs=0.02)
    _, _, nmi_identity, _ = align_rigid(CAMERA, b, compare=lambda p: np.asarray(p, float))
    assert nmi_identity < nmi - 0.01


def test_align_rigid_handles_images_of_different_sizes():
    """Rigid in pixels: a crop of b (a different size and aspect) gives the same map, shifted."""
    b, m = _pseudo_colour_pet(-4.0, (10.0, 6.0))
    crop = b[32:480, 16:500]
    matrix, _, _, _ = align_rigid(CAMERA, crop)
    pts = np.array([[150.0, 150.0], [350.0, 300.0], [250.0, 400.0]])
    want = _apply(m, pts) - [16.0, 32.0]
    assert np.abs(pts @ matrix[:, :2].T + matrix[:, 2] - want).max() < 3.0
