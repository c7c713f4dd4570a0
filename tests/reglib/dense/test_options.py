"""Tests of reglib.dense._options: DenseOptions and the estimator options of each dense fit."""
from __future__ import annotations

import dataclasses

import pytest

from reglib import L2EOptions, VFCOptions
from reglib.dense import DENSE_L2E, DENSE_VFC, DenseOptions
from reglib.errors import InputError
from reglib.options import option_specs


def test_dense_options_are_frozen_declared_and_checked():
    opts = DenseOptions()
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.step = 3  # type: ignore[misc]
    assert [s.name for s in option_specs(DenseOptions)] == [f.name for f in dataclasses.fields(DenseOptions)]
    for field, value in (("step", 0), ("radius", 257), ("rounds", 11), ("patch", 1), ("max_side", 8)):
        with pytest.raises(InputError, match=field):
            DenseOptions(**{field: value})
    with pytest.raises(InputError, match="filter"):
        DenseOptions(filter=[1, 2])  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        DenseOptions(dense_step=8)  # type: ignore[call-arg]


def test_l2e_basis_follows_the_support_at_a_fixed_kernel_width():
    opts = DenseOptions()
    few, many = opts.estimator_options(200), opts.estimator_options(2000)
    assert isinstance(few, L2EOptions) and few.start == DENSE_L2E["start"] and few.max_layers == 1
    assert few.max_centers == 50 and many.max_centers == DENSE_L2E["max_centers"]  # one per 4 matches, at most 150
    # the kernel width in normalized units is the same whatever the basis: beta * M / n_centers
    assert few.beta * few.max_centers == pytest.approx(many.beta * many.max_centers)
    # a coarser level: one centre per 6 matches, at most half as many per halving
    assert opts.estimator_options(600, level=1).max_centers == 75
    assert opts.estimator_options(6000, level=2).max_centers == int(DENSE_L2E["max_centers"] * 0.25)
    assert opts.estimator_options(10).max_centers == 15  # never below 15


def test_working_level_fit_is_less_smoothed_than_the_coarser_ones():
    from reglib.dense._options import FINAL_LAM

    opts = DenseOptions()
    assert opts.estimator_options(800).lam == FINAL_LAM == 0.1
    assert opts.estimator_options(800, level=1).lam is None  # the estimator's default (1.0 with a linear part)
    assert opts.estimator_options(800, smooth=True).lam is None  # the guard's re-fit, descriptor fields' matches
    assert DenseOptions(sparse_filter={"lam": 0.5}).estimator_options(800).lam == 0.5  # the caller's choice wins
    assert DenseOptions(filter={"max_layers": 1}).estimator_options(800).lam is None  # filter replaces all


def test_sparse_options_lay_over_the_dense_defaults_and_filter_replaces_them():
    over = DenseOptions(sparse_filter={"max_centers": 40, "beta": 0.7}).estimator_options(2000)
    assert over.max_centers == 40 and over.beta == 0.7 and over.start == DENSE_L2E["start"]
    replaced = DenseOptions(filter={"beta": 0.9}).estimator_options(2000)
    assert replaced == L2EOptions(beta=0.9)
    vfc = DenseOptions(method="vfc").estimator_options(2000)
    assert isinstance(vfc, VFCOptions) and vfc == VFCOptions(**DENSE_VFC)
    with pytest.raises(InputError, match="unknown field"):
        DenseOptions(filter={"betta": 1.0}).estimator_options(100)
