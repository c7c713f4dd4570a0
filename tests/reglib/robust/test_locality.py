"""The residual agreement of far matches (reglib.robust._locality.agreeing_far), on matches with known truth."""
import numpy as np

from reglib.robust._locality import agreeing_far

from .conftest import BUMP_CENTRE as CENTRE
from .conftest import make_bump_matches


def test_the_matches_of_a_missed_bump_agree_and_false_ones_do_not():
    for seed in range(3):
        src, dst, smooth, truth, _ = make_bump_matches(seed)
        residuals = dst - smooth  # a field that misses the bump
        e2 = (residuals**2).sum(1)
        marked = agreeing_far(src, residuals, e2, 0.25)
        in_bump = truth & (e2 >= 16.0 * 0.25)  # the true matches the field leaves far
        assert in_bump.sum() >= 30
        # enough of them to seed a fit (those at the bump's edge have explained neighbours, those amid false
        # matches too few agreeing ones)
        assert np.count_nonzero(marked & in_bump) >= 10
        assert np.count_nonzero(marked & ~truth) <= 1
        assert not marked[truth & ~in_bump].any()  # explained matches are never marked


def test_a_look_alike_group_among_explained_matches_is_not_marked():
    # a third of the matches in a disc are false and shifted by one texture period (+40 px), amid true matches
    # that the field explains
    rng = np.random.default_rng(3)
    src = rng.uniform(0.0, 500.0, (1200, 2))
    residuals = rng.normal(0.0, 0.5, src.shape)
    group = np.flatnonzero(((src - CENTRE) ** 2).sum(1) < 80.0**2)[::3]
    residuals[group] += np.array([40.0, 0.0])
    e2 = (residuals**2).sum(1)
    marked = agreeing_far(src, residuals, e2, 0.25)
    assert len(group) >= 20
    assert not marked.any()
    # the same group where nothing is explained (the field misses the whole disc) is marked
    disc = ((src - CENTRE) ** 2).sum(1) < 80.0**2
    residuals[disc & ~np.isin(np.arange(len(src)), group)] += np.array([0.0, 60.0])
    e2 = (residuals**2).sum(1)
    assert agreeing_far(src, residuals, e2, 0.25)[disc].sum() >= 10


def test_too_few_matches_mark_none():
    u = np.zeros((5, 2))
    r = np.ones((5, 2)) * 10.0
    out = agreeing_far(u, r, (r**2).sum(1), 0.25)
    assert out.shape == (5,) and out.dtype == bool and not out.any()
