"""Tests of reglib._verdict: the reason codes named once, and the decisions over measured evidence."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import reglib
from reglib._verdict import (
    FILTER_REASONS,
    IMAGE_REASONS,
    REASONS,
    REGISTRATION_REASONS,
    Reason,
    image_verdict,
    rigid_reason,
)

PACKAGE = Path(reglib.__file__).parent


def test_the_lists_partition_the_codes_and_each_is_described():
    assert len(set(REASONS)) == len(REASONS) == 12
    assert set(REASONS) == set(Reason.__args__)
    assert set(IMAGE_REASONS) == set(FILTER_REASONS) | {"unsupported", "not_settled"}
    # only a cap is shared: the shape-context image path is a registration
    assert set(IMAGE_REASONS) & set(REGISTRATION_REASONS) == {"not_settled"}
    assert list(REASONS) == list(dict.fromkeys([*IMAGE_REASONS[:-1], *REGISTRATION_REASONS]))
    assert all(len(text) > 20 for text in REASONS.values())
    assert reglib.REASONS == REASONS


def test_no_other_module_writes_a_reason_code():
    """Every code is a string literal (annotations included) in reglib/_verdict.py only; other modules'
    docstrings and comments name a code without quotes (``folding``) or by its constant."""
    found = []
    for path in PACKAGE.rglob("*.py"):
        if path.name == "_verdict.py" and path.parent == PACKAGE:
            continue
        text = path.read_text()
        for node in ast.walk(ast.parse(text, str(path))):
            if isinstance(node, ast.Constant) and node.value in REASONS:
                found.append(f"{path.relative_to(PACKAGE)}:{node.lineno}: {node.value}")
        quoted = [q + code + q for code in REASONS for q in "\"'"]
        found += [f"{path.relative_to(PACKAGE)}: {q}" for q in quoted if q in text]
    assert not found, found


@pytest.mark.parametrize(("overlap", "residual", "features", "expected"), [
    (0.05, 0.5, None, "small_overlap"),
    (0.05, 3.0, 0.0, "small_overlap"),      # the first check that fails names the reason
    (0.5, 3.0, None, "large_residual"),
    (0.5, 1.2, 0.1, "weak_features"),
    (0.5, 0.5, 0.1, None),                  # few kept, but the pose fits: a twin's inliers
    (0.3, 0.8, 0.9, None),
])
def test_rigid_reason(overlap, residual, features, expected):
    assert rigid_reason(overlap, residual, features) == expected


@pytest.mark.parametrize(("reason", "converged", "dense", "evidence", "expected"), [
    (None, True, "kept", None, (True, None)),                           # nothing measured: the estimate's word
    (None, False, "kept", None, (False, None)),                         # an iteration cap stays unconverged
    (None, True, "kept", -4.5, (False, "unsupported")),                 # worse than no motion, clearly
    (None, True, "kept", -3.9, (True, None)),
    ("too_few_inliers", True, "kept", 4.0, (True, None)),               # kept and clearly over no motion
    ("too_few_inliers", True, "sparse_better", 9.0, (False, "too_few_inliers")),
    ("too_few_inliers", True, "kept", 3.9, (False, "too_few_inliers")),
    ("too_few_inliers", True, "kept", -4.0, (False, "unsupported")),
    ("folding", True, "not_run", None, (False, "folding")),
])
def test_image_verdict(reason, converged, dense, evidence, expected):
    assert image_verdict(reason, converged, dense, evidence, 4.0) == expected


@pytest.mark.parametrize(("reason", "dense", "evidence", "expected"), [
    (None, "kept", 1.0, (False, "unsupported")),                      # moves, not rated over no motion: unusable
    (None, "no_support", -3.0, (False, "unsupported")),
    ("too_few_inliers", "kept", 1.0, (False, "too_few_inliers")),     # its own reason stays
    ("folding", "not_run", None, (False, "folding")),                 # nothing measured
])
def test_image_verdict_short_of_margin(reason, dense, evidence, expected):
    assert image_verdict(reason, True, dense, evidence, 4.0, short_of_margin=True) == expected
