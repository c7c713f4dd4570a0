import numpy as np
import pytest

from reglib import InputError, filter_matches
from reglib.robust import L2EOptions
from reglib.robust import _layers as layers
from reglib.robust._layers import LayerRule, secondary_layer


def scene_with_layer(matches, dim=2, n_layer=20, seed=0):
    """The conftest scene plus ``n_layer`` true matches of a small region that moves by its own
    translation, far from what the smooth field predicts there (a depth discontinuity)."""
    src, dst, truth, true_map = matches(n=300, outlier_rate=0.4, dim=dim, seed=seed)
    rng = np.random.default_rng(seed + 100)
    lo = np.r_[20.0, 200.0, 200.0][:dim]
    layer_src = lo + rng.uniform(0, 60, (n_layer, dim))
    shift = np.r_[260.0, -70.0, 40.0][:dim]
    layer_dst = layer_src + shift + rng.normal(0, 0.5, (n_layer, dim))
    is_layer = np.r_[np.zeros(len(src), bool), np.ones(n_layer, bool)]
    return np.r_[src, layer_src], np.r_[dst, layer_dst], np.r_[truth, np.ones(n_layer, bool)], is_layer, true_map


@pytest.mark.parametrize("dim", [2, 3])
def test_a_second_layer_is_kept_and_the_field_is_the_primary(matches, dim):
    src, dst, truth, is_layer, true_map = scene_with_layer(matches, dim)
    res = filter_matches(src, dst, rng=0)
    assert res.inliers[is_layer].mean() >= 0.9
    assert res.scores[is_layer & res.inliers].min() > 0.5
    found, real = res.inliers, truth
    precision = np.count_nonzero(found & real) / np.count_nonzero(found)
    recall = np.count_nonzero(found & real) / np.count_nonzero(real)
    assert precision >= 0.95 and recall >= 0.95
    # The transform is the primary layer's: it maps the primary's true matches, not the layer's.
    primary = truth & ~is_layer
    err = np.linalg.norm(res.transform(src[primary]) - true_map(src[primary]), axis=1)
    assert np.median(err) < 3.0
    assert np.linalg.norm(res.transform(src[is_layer]) - dst[is_layer], axis=1).min() > 50.0


def test_one_layer_rejects_them(matches):
    src, dst, _, is_layer, _ = scene_with_layer(matches)
    res = filter_matches(src, dst, options={"max_layers": 1}, rng=0)
    assert res.inliers[is_layer].mean() <= 0.1


def test_a_group_below_min_layer_matches_is_not_a_layer(matches):
    src, dst, _, is_layer, _ = scene_with_layer(matches, n_layer=6)
    res = filter_matches(src, dst, rng=0)
    assert res.inliers[is_layer].sum() <= 1


def test_a_group_among_the_primary_inliers_is_not_a_layer(matches, monkeypatch):
    """A group that moves together but whose points lie among the primary inliers (look-alikes of a
    repeated texture) occupies no region of its own: it is no separately moving part."""
    src, dst, truth, _ = matches(n=300, outlier_rate=0.4, seed=0)
    rng = np.random.default_rng(100)
    beside = src[rng.choice(np.flatnonzero(truth), 20, replace=False)] + rng.normal(0, 3.0, (20, 2))
    src, dst = np.r_[src, beside], np.r_[dst, beside + [260.0, -70.0] + rng.normal(0, 0.5, (20, 2))]
    is_group = np.r_[np.zeros(len(truth), bool), np.ones(20, bool)]
    assert filter_matches(src, dst, rng=0).inliers[is_group].sum() <= 1
    monkeypatch.setattr(layers, "_REGION_SHARE", 1.0)  # without the rule, the group is kept as a layer
    assert filter_matches(src, dst, rng=0).inliers[is_group].mean() >= 0.9


@pytest.mark.parametrize("outlier_rate, n", [(0.8, 2000), (0.95, 5000)])
def test_uniform_outliers_make_no_layer(matches, outlier_rate, n):
    src, dst, truth, _ = matches(n=n, outlier_rate=outlier_rate, seed=3)
    with_layers = filter_matches(src, dst, rng=0)
    without = filter_matches(src, dst, options={"max_layers": 1}, rng=0)
    np.testing.assert_array_equal(with_layers.inliers, without.inliers)


def test_secondary_layer_needs_more_than_chance():
    rng = np.random.default_rng(0)
    u = rng.uniform(-1, 1, (200, 2))
    y = u + rng.uniform(-1, 1, (200, 2))  # no structure at all
    y[:12] = u[:12] + [0.5, 0.2]  # 12 that move together
    rejected = np.arange(200)
    rule = LayerRule(min_matches=8, score_scale=1.5, threshold=0.5)
    layer = secondary_layer(u, y, y - u, rejected, rejected, 0.01**2, 4.0, rule)
    assert layer is not None and set(layer.members.tolist()) == set(range(12))
    np.testing.assert_allclose(layer.affine, [[1, 0, 0.5], [0, 1, 0.2]], atol=1e-9)
    # Far fewer of them than min_matches, or a scale so wide that chance explains them: none.
    strict = LayerRule(min_matches=13, score_scale=1.5, threshold=0.5)
    assert secondary_layer(u, y, y - u, rejected, rejected, 0.01**2, 4.0, strict) is None
    assert secondary_layer(u, y, y - u, rejected, rejected, 0.2**2, 4.0, rule) is None


@pytest.mark.parametrize("field, value", [("max_layers", 0), ("max_layers", 3), ("max_layers", 1.5),
                                          ("min_layer_matches", 3), ("fine_iter", -1)])
def test_layer_options_are_checked(field, value):
    with pytest.raises(InputError, match=field):
        L2EOptions(**{field: value})


def scene_with_turned_layer(matches, n_layer=20, turn_deg=50.0, seed=0):
    """The conftest scene plus ``n_layer`` true matches of a region that turns by ``turn_deg`` as it
    moves: its displacements differ by tens of pixels across it, so they share no translation."""
    src, dst, truth, _ = matches(n=300, outlier_rate=0.4, seed=seed)
    rng = np.random.default_rng(seed + 100)
    layer_src = np.r_[20.0, 200.0] + rng.uniform(0, 100, (n_layer, 2))
    a = np.deg2rad(turn_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    centre = np.r_[70.0, 250.0]
    layer_dst = (layer_src - centre) @ rot.T + centre + [260.0, -70.0] + rng.normal(0, 0.5, (n_layer, 2))
    is_layer = np.r_[np.zeros(len(src), bool), np.ones(n_layer, bool)]
    return np.r_[src, layer_src], np.r_[dst, layer_dst], np.r_[truth, np.ones(n_layer, bool)], is_layer


def test_a_turned_layer_is_found_by_its_similarity(matches, monkeypatch):
    src, dst, truth, is_layer = scene_with_turned_layer(matches)
    res = filter_matches(src, dst, rng=0)
    assert res.inliers[is_layer].mean() >= 0.9
    found = res.inliers
    assert np.count_nonzero(found & truth) / np.count_nonzero(found) >= 0.95
    # Without the similarity proposals the displacement hashing alone misses it.
    monkeypatch.setattr(layers, "_PAIR_NEIGHBOURS", 0)
    assert filter_matches(src, dst, rng=0).inliers[is_layer].mean() <= 0.1
