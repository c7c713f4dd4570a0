"""Tests of reglib.match_images on pairs made with a known warp (ground truth by construction)."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import skimage.data

from reglib import ImageMatch, KernelWarp, MatchOptions, dense_flow, match_images
from reglib.errors import ImageTooLarge, InputError

SMALL = {"max_keypoints": 600}


def _backward(p: np.ndarray) -> np.ndarray:
    """h: b -> a, a rotation by 6 degrees about the centre, a shift and a smooth bend (pixels of a 384 image)."""
    c = np.array([192.0, 192.0])
    ang = np.deg2rad(6.0)
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    q = (p - c) @ rot.T / 1.05 + c + [6.0, -4.0]
    return q + np.c_[7.0 * np.sin(p[:, 1] / 60.0), 5.0 * np.cos(p[:, 0] / 70.0)]


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    a = skimage.data.astronaut()[40:424, 60:444].copy()  # 384 x 384 RGB
    ys, xs = np.mgrid[0:384, 0:384]
    m = _backward(np.c_[xs.ravel(), ys.ravel()].astype(float)).astype(np.float32).reshape(384, 384, 2)
    b = cv2.remap(a, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return a, b


def _a_error(match: ImageMatch, pts: np.ndarray) -> np.ndarray:
    """|h(f(p)) - p|: how far f(p) is from the true position, measured back in a (h scales by ~1/1.05)."""
    return np.linalg.norm(_backward(match.transform(pts)) - pts, axis=1)


def test_sparse_recovers_a_non_rigid_warp_and_the_inliers(pair):
    a, b = pair
    m = match_images(a, b, rng=0, options={**SMALL, "dense": False})
    assert isinstance(m, ImageMatch) and m.reason is None
    assert m.src.shape == m.dst.shape == (m.n_matches, 2) and m.n_matches > 100
    truth = np.linalg.norm(_backward(m.dst) - m.src, axis=1) < 3.0
    kept = m.inliers
    precision = (kept & truth).sum() / kept.sum()
    recall = (kept & truth).sum() / truth.sum()
    assert precision > 0.95 and recall > 0.9
    grid = np.mgrid[60:330:15, 60:330:15].reshape(2, -1).T[:, ::-1].astype(float)
    assert np.median(_a_error(m, grid)) < 1.5
    assert m.fold_fraction == 0.0
    assert set(m.timings_ms) >= {"features", "matching", "filter", "total"}


def test_dense_refinement_is_accurate_to_the_pixel(pair):
    a, b = pair
    m = match_images(a, b, rng=0, options=SMALL)
    assert m.n_dense > 200 and "dense" in m.timings_ms
    grid = np.mgrid[40:344:8, 40:344:8].reshape(2, -1).T[:, ::-1].astype(float)
    err = _a_error(m, grid)
    assert err.mean() < 1.0 and np.mean(err < 3.0) > 0.95
    flow = dense_flow(m.transform, m.shape_a)
    p = np.array([[200.0, 150.0]])
    assert np.allclose(flow[150, 200], (m.transform(p) - p)[0], atol=0.05)


def test_same_seed_same_answer(pair):
    a, b = pair
    one = match_images(a, b, rng=3, options={**SMALL, "dense": False}).to_dict()
    two = match_images(a, b, rng=3, options={**SMALL, "dense": False}).to_dict()
    one.pop("timings_ms"), two.pop("timings_ms")
    assert one == two
    assert one["seed"] == 3


def test_to_dict_is_the_contract_json(pair):
    a, b = pair
    m = match_images(a, b, rng=0, options={**SMALL, "dense": False})
    d = json.loads(json.dumps(m.to_dict()))
    assert set(d) >= {"n_matches", "n_inliers", "src", "dst", "inliers", "scores", "transform", "converged",
                      "reason", "seed", "timings_ms", "shape_a", "shape_b", "fold_fraction"}
    assert d["inliers"] == sorted(d["inliers"]) and len(d["inliers"]) == d["n_inliers"] == m.n_inliers
    assert np.array_equal(np.flatnonzero(m.inliers), d["inliers"])
    assert d["shape_a"] == [384, 384]
    t = KernelWarp.from_dict(d["transform"])
    assert np.allclose(t(m.src[:5]), m.transform(m.src[:5]))


@pytest.mark.parametrize("blank", [np.zeros((64, 80), np.uint8), np.full((1, 1), 9, np.uint8),
                                   np.full((50, 3), 1.0)])
def test_no_texture_is_the_too_few_matches_answer(blank):
    m = match_images(blank, blank, rng=0)
    assert m.reason == "too_few_matches" and m.converged is False
    assert m.src.shape == (0, 2) and m.inliers.shape == (0,) and m.scores.shape == (0,)
    assert m.keypoints_a.shape == (0, 2)
    p = np.array([[1.0, 2.0]])
    assert np.array_equal(m.transform(p), p)
    assert m.to_dict()["inliers"] == []


def test_downscaled_detection_maps_coordinates_back_exactly():
    a = skimage.data.camera()
    b = cv2.warpAffine(a, np.float32([[1, 0, 9], [0, 1, -6]]), (512, 512))
    m = match_images(a, b, rng=0, options={"max_side": 200, "dense": False})
    res = m.dst[m.inliers] - m.src[m.inliers]
    assert m.n_inliers > 30
    assert np.allclose(np.median(res, axis=0), [9, -6], atol=0.3)
    assert m.keypoints_a.max() <= 511.5


def test_other_dtypes_and_alpha_give_the_same_motion():
    a = skimage.data.camera()
    b = cv2.warpAffine(a, np.float32([[1, 0, 5], [0, 1, 4]]), (512, 512))
    a16, b16 = a.astype(np.uint16) * 257, b.astype(np.uint16) * 257
    af, bf = a.astype(np.float64) / 255.0, b.astype(np.float64) / 255.0
    ref = match_images(a, b, rng=0, options={"dense": False, "max_keypoints": 300})
    # 8 bits keep their values (a 4th band, alpha, does not steer the features): the same answer bit for bit
    m = match_images(np.dstack([a, a, a, a]), np.dstack([b, b, b, b]), rng=0,
                     options={"dense": False, "max_keypoints": 300})
    assert np.array_equal(m.src, ref.src) and np.array_equal(m.inliers, ref.inliers)
    # other depths are stretched by their percentiles: other keypoints, the same motion
    probe = np.array([[100.0, 100.0], [400.0, 300.0]])
    for x, y in ((a16, b16), (af, bf)):
        m = match_images(x, y, rng=0, options={"dense": False, "max_keypoints": 300})
        assert m.converged and m.n_inliers >= 0.8 * ref.n_inliers
        np.testing.assert_allclose(m.transform(probe), probe + [5, 4], atol=0.5)


def test_masks_restrict_keypoints():
    a = skimage.data.camera()
    mask = np.zeros(a.shape, bool)
    mask[:, :200] = True
    m = match_images(a, a, rng=0, mask_a=mask, options={"dense": False, "max_keypoints": 300})
    assert m.keypoints_a[:, 0].max() < 205
    assert m.keypoints_b[:, 0].max() > 300


def test_mutual_and_ratio_options(pair):
    a, b = pair
    loose = match_images(a, b, rng=0, options={**SMALL, "dense": False, "ratio": 1.0})
    strict = match_images(a, b, rng=0, options={**SMALL, "dense": False, "ratio": 1.0, "mutual": True})
    assert loose.n_matches == len(loose.keypoints_a)  # every nearest neighbour
    assert strict.n_matches < loose.n_matches
    assert set(map(tuple, strict.src)) <= set(map(tuple, loose.src))


def test_encoded_inputs_and_pixel_limit(tmp_path):
    a = skimage.data.camera()
    ok, buf = cv2.imencode(".png", a)
    path = tmp_path / "a.png"
    path.write_bytes(buf.tobytes())
    m = match_images(path, buf.tobytes(), rng=0, options={"dense": False, "max_keypoints": 200})
    assert m.shape_a == m.shape_b == (512, 512)
    with pytest.raises(ImageTooLarge, match="image_a"):
        match_images(path, path, options={"max_pixels": 1000})


@pytest.mark.parametrize("kwargs,words", [
    ({"options": {"ratioo": 0.7}}, "unknown field"),
    ({"options": {"ratio": 0.0}}, "ratio"),
    ({"options": {"ratio": 1.5}}, "ratio"),
    ({"options": {"max_keypoints": 0}}, "max_keypoints"),
    ({"options": {"dense": "yes"}}, "dense"),
    ({"options": {"filter": {"bogus": 1}}}, "bogus"),
    ({"options": {"dense_filter": {"betta": 1}}}, "dense_filter"),
    ({"method": "vfc", "options": {"filter": {"max_centers": 9}}}, "max_centers"),
    ({"features": "orb"}, "features"),
    ({"method": "ransac"}, "method"),
    ({"mask_a": np.ones((3, 3), bool)}, "mask_a"),
    ({"rng": "seed"}, "rng"),
])
def test_bad_arguments_are_input_errors(kwargs, words):
    a = np.zeros((32, 32), np.uint8)
    with pytest.raises(InputError, match=words):
        match_images(a, a, **kwargs)


def test_bad_images_are_input_errors():
    with pytest.raises(InputError, match="image_b"):
        match_images(np.zeros((8, 8)), b"garbage bytes")
    with pytest.raises(InputError, match="image_a.*empty"):
        match_images(np.zeros((0, 8)), np.zeros((8, 8)))
    with pytest.raises(InputError, match="NaN"):
        match_images(np.full((8, 8), np.nan), np.zeros((8, 8)))


def test_match_options_is_frozen():
    opts = MatchOptions()
    with pytest.raises(AttributeError):
        opts.ratio = 0.5  # type: ignore[misc]


def test_the_dense_stage_runs_with_the_match_options_dense_fields():
    from reglib.dense import DenseOptions
    from reglib.matching._dense import dense_options

    opts = MatchOptions(dense_step=12, dense_radius=9, dense_rounds=3, dense_patch=4, max_side=800,
                        filter={"beta": 0.5}, dense_filter={"max_centers": 40}, dense_detail=True)
    assert dense_options(opts, "vfc") == DenseOptions(method="vfc", step=12, radius=9, rounds=3, patch=4, max_side=800,
                                                      filter={"max_centers": 40}, sparse_filter={"beta": 0.5},
                                                      detail=True)
    defaults = dense_options(MatchOptions(), "l2e")
    assert defaults == DenseOptions() and defaults.sparse_filter is None and defaults.filter is None
    assert not defaults.detail


# ------------------------------------------------------------------------------ shape context
def _blob(theta: np.ndarray) -> np.ndarray:
    r = 90 + 25 * np.sin(3 * theta) + 15 * np.cos(2 * theta + 1)  # no rotational symmetry
    return np.c_[150 + r * np.cos(theta), 150 + r * np.sin(theta)]


def _bend(p: np.ndarray) -> np.ndarray:
    ang = np.deg2rad(15)
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    q = (p - 150.0) @ rot.T * 1.05 + 150.0 + [5, -3]
    return q + np.c_[6 * np.sin(p[:, 1] / 50), 4 * np.cos(p[:, 0] / 60)]


def test_shape_context_registers_a_bent_silhouette():
    from scipy.spatial import cKDTree

    poly = _blob(np.linspace(0, 2 * np.pi, 400, endpoint=False))
    a = np.zeros((300, 300), np.uint8)
    b = np.zeros((300, 300), np.uint8)
    cv2.fillPoly(a, [poly.round().astype(np.int32)], 255)
    cv2.fillPoly(b, [_bend(poly).round().astype(np.int32)], 255)
    m = match_images(a, b, features="shape_context", rng=0)
    assert m.n_matches > 100 and m.n_inliers > 0.8 * m.n_matches
    # edge samples slide along the contour, so the rounds may end before they settle: then it says so
    assert m.reason in (None, "not_settled") and m.converged == (m.reason is None)
    # points slide along a contour, so measure the distance to the true target curve
    curve = cKDTree(_bend(_blob(np.linspace(0, 2 * np.pi, 4000, endpoint=False))))
    moved, _ = curve.query(m.transform(poly))
    still, _ = curve.query(poly)
    assert still.mean() > 8 and moved.mean() < 2.0
    assert m.keypoints_a.shape[1] == 2 and len(m.keypoints_a) <= 300


def test_shape_context_without_edges_is_the_too_few_answer():
    m = match_images(np.zeros((40, 40), np.uint8), np.zeros((40, 40), np.uint8), features="shape_context")
    assert m.reason == "too_few_matches" and m.src.shape == (0, 2) and not m.converged


def test_dense_refinement_on_a_downscaled_copy_maps_back():
    a = skimage.data.camera()
    b = cv2.warpAffine(a, np.float32([[1, 0, 9.5], [0, 1, -6.25]]), (512, 512), flags=cv2.INTER_CUBIC)
    m = match_images(a, b, rng=0, options={"max_side": 256, "max_keypoints": 500})
    assert m.n_dense > 100
    p = np.mgrid[100:400:50, 100:400:50].reshape(2, -1).T.astype(float)
    err = np.abs(m.transform(p) - p - [9.5, -6.25])
    assert np.median(err) < 0.15  # a half-pixel slip in mapping the copy back would show here
    assert err.max() < 1.5


def test_save_match_layout(pair, tmp_path):
    from reglib.outputs import save_match

    a, b = pair
    m = match_images(a, b, rng=0, options={**SMALL, "dense": False})
    written = save_match(m, tmp_path / "o1")
    # no images given: no pictures; no dense stage: no confidence map
    assert m.converged and list(written) == ["transform", "flow", "match"]
    written = save_match(m, tmp_path / "o2", image_a=a, image_b=b, flow_format="mha")
    assert list(written)[-1] == "match"  # written last: its presence means the folder is complete
    assert sorted(p.name for p in (tmp_path / "o2").iterdir()) == sorted(f"{k}{s}" for k, s in [
        ("transform", ".json"), ("flow", ".mha"), ("warped", ".png"), ("matches", ".png"),
        ("overlay", ".png"), ("match", ".json")])
    body = json.loads((tmp_path / "o2" / "match.json").read_text())
    assert body["n_inliers"] == m.n_inliers
    with pytest.raises(InputError, match="image_b"):
        save_match(m, tmp_path / "o3", image_a=a, image_b=b[:100])
    with pytest.raises(InputError, match="flow_format"):
        save_match(m, tmp_path / "o4", flow_format="png")


def test_an_unconverged_answer_gets_no_files_of_its_motion(pair, tmp_path):
    from reglib.outputs import save_match, writes_motion

    a, _ = pair
    noise = np.random.default_rng(3).integers(0, 256, a.shape, dtype=np.uint8)
    m = match_images(a, noise, rng=0, options=SMALL)
    assert not m.converged and m.reason is not None and not writes_motion(m)
    written = save_match(m, tmp_path / "o", image_a=a, image_b=noise)
    # the evidence and the transform, for a look; nothing a pipeline could pick up as the motion
    assert list(written) == ["transform", "matches", "match"]
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["match.json", "matches.png", "transform.json"]
    assert json.loads((tmp_path / "o" / "match.json").read_text())["converged"] is False


@pytest.mark.parametrize("field, value", [("dense_radius", 257), ("dense_rounds", 11), ("dense_patch", 65),
                                          ("contour_points", 20001)])
def test_sizes_that_would_run_without_end_are_refused(field, value):
    with pytest.raises(InputError, match=field):
        MatchOptions(**{field: value})


# ----------------------------------------------------------------------------- multimodal estimate

def test_multimodal_fit_falls_back_to_the_rigid_nmi_map_when_features_find_too_little():
    """A handful of false matches (what the features give on MR / PET): the rigid NMI map answers."""
    from reglib.matching._multimodal import multimodal_fit

    a = skimage.data.camera()
    m = cv2.getRotationMatrix2D((255.5, 255.5), 5.0, 1.0)
    m[:, 2] += (12.0, -9.0)
    b = cv2.GaussianBlur(cv2.warpAffine(255 - a, m, (512, 512)), (0, 0), 4.0)
    rng = np.random.default_rng(0)
    src, dst = rng.uniform(50, 460, (8, 2)), rng.uniform(50, 460, (8, 2))
    res = multimodal_fit(a, b, src, dst, np.random.default_rng(0))
    # the map answers, but no match backs it: said, not hidden
    assert res.reason == "too_few_inliers" and not res.converged
    grid = np.stack(np.meshgrid(np.linspace(80, 430, 5), np.linspace(80, 430, 5)), -1).reshape(-1, 2)
    want = grid @ m[:, :2].T + m[:, 2]
    assert np.abs(res.transform(grid) - want).max() < 3.0
    assert res.inliers.shape == (8,) and res.transform.linear is not None
    # with enough matches that agree with the motion, the answer is a converged one
    good = rng.uniform(60, 450, (20, 2))
    backed = multimodal_fit(a, b, np.r_[src[:3], good], np.r_[dst[:3], good @ m[:, :2].T + m[:, 2]],
                            np.random.default_rng(0))
    assert np.abs(backed.transform(grid) - want).max() < 3.0
    assert backed.n_inliers >= 12 and backed.reason is None
    # no structure at all stays the too-few-matches answer
    blank = np.zeros((64, 80), np.uint8)
    none = match_images(blank, blank, features="multimodal", rng=0)
    assert none.reason == "too_few_matches" and none.src.shape == (0, 2)


def test_thin_or_long_images_are_the_too_few_matches_answer():
    # a 2 px or 16 px side: the multimodal path's detection and confidence map raised before
    rng = np.random.default_rng(0)
    for shape in ((2, 3000), (16, 3000), (3000, 16)):
        img = rng.integers(0, 255, shape).astype(np.uint8)
        for features in ("multimodal", "sift", "auto"):
            m = match_images(img, img, features=features, rng=0)
            assert m.src.shape[1] == 2
            # a map exactly when a dense stage ran
            assert (m.confidence is None) == (m.dense == "not_run")
            assert m.confidence is None or m.confidence.shape == shape
            if features == "multimodal":
                assert m.reason == "too_few_matches" and m.src.shape == (0, 2)


def test_an_answer_short_of_the_margin_over_no_motion_is_unsupported(pair, monkeypatch):
    # the true warp's answer is usable; the same answer with the images' rating replaced by one a wrong motion
    # gets across stains (clearly moved, z 3 but the more similar at only 55 % of the places) is refused
    import reglib.matching._pipeline as pipeline
    from reglib.dense import OverNoMotion

    a, b = pair
    good = match_images(a, b, rng=0, options=SMALL)
    assert good.converged and good.reason is None
    grid = np.mgrid[40:344:16, 40:344:16].reshape(2, -1).T[:, ::-1].astype(float)
    assert np.median(_a_error(good, grid)) < 1.5
    real, seen = pipeline.rate_over_no_motion, []

    def rated(*args):
        seen.append(real(*args))
        return OverNoMotion(z=3.0, share=0.55, moved=10.0)

    monkeypatch.setattr(pipeline, "rate_over_no_motion", rated)
    refused = match_images(a, b, rng=0, options=SMALL)
    assert not refused.converged and refused.reason == "unsupported"
    np.testing.assert_array_equal(refused.transform(grid), good.transform(grid))  # the verdict alone moved
    assert seen and seen[0].moved > 2.0 and not seen[0].short_of_margin  # the real rating backs the answer


def test_a_region_where_the_answer_is_no_peak_is_unsupported_where_sift_was_asked_for(pair, monkeypatch):
    # the same answer with a rating that is right over the whole image but no peak in one region: refused when the
    # caller asked for SIFT matches (one modality); kept from the multimodal features and from "auto", also where
    # "auto" answers by SIFT (across sensors a right answer can be a weaker peak in a region)
    import reglib.matching._pipeline as pipeline
    from reglib.dense import OverNoMotion

    a, b = pair
    real = pipeline.rate_over_no_motion

    def rated(*args):
        r = real(*args)
        return OverNoMotion(z=r.z, share=r.share, moved=r.moved, neighbours=r.neighbours, places=r.places,
                            weakest=0.5, weakest_z=6.0)

    monkeypatch.setattr(pipeline, "rate_over_no_motion", rated)
    sift = match_images(a, b, features="sift", rng=0, options=SMALL)
    assert sift.features == "sift" and not sift.converged and sift.reason == "unsupported"
    multi = match_images(a, b, features="multimodal", rng=0, options=SMALL)
    assert multi.features == "multimodal" and multi.reason != "unsupported"
    auto = match_images(a, b, features="auto", rng=0, options=SMALL)
    assert auto.features == "sift" and auto.converged and auto.reason is None
