"""The coarse stage's choice and the rounds of an ICP still climbing (reglib.registration._coarse).

A toy ICP on one number: the pose is a (3, 4) matrix whose translation x moves toward a goal by a fixed
step an iteration; it converges when it reaches the goal. Its score is known in closed form, so which start
wins, and after how many iterations, is ground truth.
"""
from __future__ import annotations

import numpy as np

from reglib.registration import _coarse
from reglib.registration._coarse import coarse_winner, go_on
from reglib.registration._rigid import RigidFit


def _pose(x: float) -> np.ndarray:
    return np.c_[np.eye(3), [x, 0.0, 0.0]]


def _toy(goals: dict[float, float], speed: float, noise: float = 0.0, n_points: int = 200):
    """run(matrix, n): x moves toward the goal of the basin it starts in (the nearest key) by ``speed``;
    scores_of(matrix): the score max(height - |x - goal|) on each of ``n_points`` sample points, plus, with
    ``noise``, a per-point term drawn afresh for each pose (the sampling noise of a real score)."""
    def run(matrix: np.ndarray, n: int) -> RigidFit:
        x = float(matrix[0, 3])
        goal = min(goals, key=lambda g: abs(g - x))
        it = 0
        for it in range(1, n + 1):
            if abs(goal - x) <= 1e-12:
                return RigidFit(matrix=_pose(x), n_iter=it - 1, converged=True, reach=1.0)
            x += float(np.clip(goal - x, -speed, speed))
        return RigidFit(matrix=_pose(x), n_iter=it, converged=abs(goal - x) <= 1e-12, reach=1.0)

    def scores_of(matrix: np.ndarray) -> np.ndarray:
        x = float(matrix[0, 3])
        base = max(height - abs(x - goal) for goal, height in goals.items())
        terms = np.random.default_rng(round(abs(x) * 1e6)).normal(0.0, noise, n_points)
        return base + terms - terms.mean()

    def score(matrix: np.ndarray) -> float:
        return float(scores_of(matrix).mean())
    return run, scores_of, score


def test_slow_true_start_wins_after_more_rounds() -> None:
    # the true pose (x = 0, score 1) is 4 units from its start and moves 0.05 an iteration: capped at 50 it is
    # 1.5 away (score -0.5); a wrong pose (x = 10, score 0.6) is reached at once: without more rounds it wins
    run, scores_of, _ = _toy({0.0: 1.0, 10.0: 0.6}, speed=0.05)
    won = coarse_winner([_pose(-4.0), _pose(9.0)], run, scores_of, lambda i, m: True, 50)
    assert abs(won.matrix[0, 3]) < 1e-9 and won.converged
    assert won.n_iter == 80


def test_without_rounds_the_wrong_start_wins(monkeypatch) -> None:
    monkeypatch.setattr(_coarse, "_ROUNDS", 0)
    run, scores_of, _ = _toy({0.0: 1.0, 10.0: 0.6}, speed=0.05)
    won = coarse_winner([_pose(-4.0), _pose(9.0)], run, scores_of, lambda i, m: True, 50)
    assert abs(won.matrix[0, 3] - 10.0) < 1e-9


def test_go_on_stops_at_the_round_limit_and_on_no_gain() -> None:
    run, _, score = _toy({0.0: 1.0}, speed=0.001)  # each round of 50 gains 0.05: climbs every round
    fit = run(_pose(-10.0), 50)
    more, s = go_on(fit, run, score, score(fit.matrix), 50)
    assert more.n_iter == 50 * (1 + _coarse._ROUNDS) and not more.converged
    assert abs(s - score(more.matrix)) < 1e-12
    run, _, score = _toy({0.0: 1.0}, speed=1e-6)   # a creeping run: one more round, no gain, stop
    fit = run(_pose(-10.0), 50)
    more, _ = go_on(fit, run, score, score(fit.matrix), 50)
    assert more.n_iter == 100


def test_go_on_leaves_a_converged_fit() -> None:
    run, _, score = _toy({0.0: 1.0}, speed=1.0)
    fit = run(_pose(-3.0), 50)
    assert fit.converged
    assert go_on(fit, run, score, score(fit.matrix), 50)[0] is fit


def test_a_runner_up_within_the_noise_does_not_take_the_lead() -> None:
    # the slow start ends 0.01 over the settled one, but each pose's per-point terms scatter by 0.3 over 200
    # points (a standard error of the paired difference ~0.03): not a clear lead, the settled pose stays
    run, scores_of, _ = _toy({0.0: 0.61, 10.0: 0.6}, speed=0.05, noise=0.3)
    won = coarse_winner([_pose(-4.0), _pose(9.0)], run, scores_of, lambda i, m: True, 50)
    assert abs(won.matrix[0, 3] - 10.0) < 1e-9
    # the same lead without the noise is clear
    run, scores_of, _ = _toy({0.0: 0.61, 10.0: 0.6}, speed=0.05)
    won = coarse_winner([_pose(-4.0), _pose(9.0)], run, scores_of, lambda i, m: True, 50)
    assert abs(won.matrix[0, 3]) < 1e-9


def test_point_scores_are_the_overlap_scores_terms() -> None:
    from scipy.spatial import cKDTree

    from reglib.registration._support import overlap_score, point_scores
    tree = cKDTree(np.zeros((1, 3)))
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]])
    terms = point_scores(tree, pts, 1.0)
    assert np.allclose(terms, [1.0, 0.75, 0.0, 0.0])
    assert overlap_score(tree, pts, 1.0) == float(terms.mean())
