"""Failure modes of issue 12 on synthetic scenes with ground truth: large scale changes and
rotations, a low inlier share, seed stability, and a failure that is said (``reason``)."""
import numpy as np
import pytest

from reglib import FilterResult, filter_matches

REASONS = ("too_few_matches", "too_few_inliers", "small_cluster", "folding")  # FilterResult's documented list


def scene(n=300, outlier_rate=0.5, scale=1.0, degrees=0.0, amplitude=20.0, wavelength=600.0, zoom=False,
          box=1000.0, seed=0):
    """src uniform in a box; true dst = a similarity of src plus a smooth field plus 1 px noise.

    ``zoom``: image b is a close-up of the middle of image a (the true matches come from the
    central box / scale of a and fill b); false matches anywhere in either image.
    """
    rng = np.random.default_rng(seed)
    centre = np.full(2, box / 2)
    bad = rng.random(n) < outlier_rate
    src = rng.uniform(0, box, (n, 2))
    if zoom:
        side = box / scale
        src[~bad] = rng.uniform(centre - side / 2, centre + side / 2, (int((~bad).sum()), 2))
    field = np.zeros_like(src)
    for comp in range(2):
        k = rng.normal(size=2)
        k *= 2 * np.pi / wavelength / np.linalg.norm(k)
        field[:, comp] = amplitude * np.sin(src @ k + rng.uniform(0, 2 * np.pi))
    t = np.deg2rad(degrees)
    rot = scale * np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    clean = (src + field - centre) @ rot.T + centre
    dst = clean + rng.normal(0, 1.0, src.shape)
    lo, hi = (np.zeros(2), np.full(2, box)) if zoom else (clean[~bad].min(0), clean[~bad].max(0))
    dst[bad] = rng.uniform(lo, hi, (int(bad.sum()), 2))
    return src, dst, ~bad


def f1(found, truth):
    tp = np.count_nonzero(found & truth)
    p, r = tp / max(np.count_nonzero(found), 1), tp / max(np.count_nonzero(truth), 1)
    return 2 * p * r / max(p + r, 1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_threefold_zoom_among_many_false_matches(seed):
    # The true matches are one cluster in a's middle (a ninth of its area) among 80 % false
    # matches spread over both images: the first estimate must not lock onto the false ones.
    src, dst, truth = scene(n=300, outlier_rate=0.8, scale=3.0, zoom=True, seed=seed)
    res = filter_matches(src, dst, rng=0)
    assert f1(res.inliers, truth) >= 0.95
    assert res.converged and res.reason is None


@pytest.mark.parametrize("degrees, scale", [(180.0, 1.0), (150.0, 3.0), (-135.0, 1 / 3)])
def test_any_rotation_and_a_large_scale_change(degrees, scale):
    src, dst, truth = scene(n=400, outlier_rate=0.5, degrees=degrees, scale=scale, seed=4)
    res = filter_matches(src, dst, rng=0)
    assert f1(res.inliers, truth) >= 0.98


def test_low_inlier_share_with_a_rotation():
    # 10 % true matches, rotated by 60 degrees: a start from the identity finds only false ones.
    src, dst, truth = scene(n=1000, outlier_rate=0.9, degrees=60.0, seed=1)
    res = filter_matches(src, dst, rng=0)
    assert f1(res.inliers, truth) >= 0.95


def test_the_same_inliers_for_every_seed():
    # Today's seeded subsets and centres give F1 0.974-0.992 here, and ten different inlier sets.
    src, dst, truth = scene(n=1500, outlier_rate=0.7, amplitude=50.0, wavelength=400.0, seed=3)
    results = [filter_matches(src, dst, rng=seed) for seed in range(10)]
    for res in results[1:]:
        np.testing.assert_array_equal(res.inliers, results[0].inliers)
    assert f1(results[0].inliers, truth) >= 0.95


def test_random_matches_are_said_to_fail():
    rng = np.random.default_rng(0)
    src, dst = rng.uniform(0, 1000, (300, 2)), rng.uniform(0, 1000, (300, 2))
    res = filter_matches(src, dst, rng=0)
    assert not res.converged
    assert res.reason in REASONS and res.reason != "too_few_matches"


def test_a_small_cluster_is_said_to_fail():
    # 40 matches that agree, packed in 2 % of both images, among 200 random ones.
    rng = np.random.default_rng(1)
    cluster = rng.uniform(470, 530, (40, 2))
    src = np.r_[cluster, rng.uniform(0, 1000, (200, 2))]
    dst = np.r_[cluster + [3.0, -2.0] + rng.normal(0, 0.5, (40, 2)), rng.uniform(0, 1000, (200, 2))]
    res = filter_matches(src, dst, rng=0)
    assert not res.converged and res.reason == "small_cluster"
    assert res.inliers[:40].all()  # the estimate is still returned


def test_few_true_matches_are_said_to_fail():
    rng = np.random.default_rng(2)
    good = rng.uniform(0, 1000, (7, 2))
    src = np.r_[good, rng.uniform(0, 1000, (300, 2))]
    dst = np.r_[good + [10.0, 5.0], rng.uniform(0, 1000, (300, 2))]
    res = filter_matches(src, dst, rng=0)
    assert not res.converged and res.reason == "too_few_inliers"


def test_a_good_scene_has_no_reason():
    src, dst, truth = scene(n=400, outlier_rate=0.5, seed=5)
    res = filter_matches(src, dst, rng=0)
    assert res.converged and res.reason is None and f1(res.inliers, truth) >= 0.98


def test_every_reason_is_documented():
    from reglib._verdict import FILTER_REASONS

    assert set(FILTER_REASONS) == set(REASONS)
    for reason in REASONS:
        assert f"``{reason}``" in FilterResult.__doc__


def test_less_precise_true_matches_are_kept_beside_very_precise_ones(matches):
    """Real feature matches mix very precise and less precise ones (here 0.05 px and 0.8 px). A fine
    level fitted on them pulls the field onto each, shrinking their residuals below the real
    spread; judged so, the less precise true matches fell out (recall 0.82-0.89 before the
    decision used left-out residuals)."""
    recall, found = [], []
    for seed in range(3):
        src, dst, truth, true_map = matches(n=3000, outlier_rate=0.8, seed=seed, noise=0.05)
        rng = np.random.default_rng(seed + 100)
        loose = truth & (rng.random(len(src)) < 0.3)
        dst[loose] = true_map(src[loose]) + rng.normal(0, 0.8, (int(loose.sum()), 2))
        res = filter_matches(src, dst, rng=0)
        recall.append(res.inliers[loose].mean())
        found.append(f1(res.inliers, truth))
    assert np.mean(recall) >= 0.95, recall
    assert min(found) >= 0.98, found
