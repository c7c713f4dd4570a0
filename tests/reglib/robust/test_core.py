"""The weighted ridge solve shared by L2E and VFC: its leverage (the hat matrix's trace, shared out)."""
import numpy as np
import pytest

from reglib.robust import Model, WeightedSolver, identity_model, ridge_epsilon


def exact_hat_trace(solver, p, ridge):
    """tr(X (X^T P X + R)^-1 X^T P) by brute force, R the ridge on the kernel block plus the solve's epsilon."""
    x = solver.design
    a = x.T @ (p[:, None] * x)
    a[solver.n_lin:, solver.n_lin:] += ridge * solver.gram
    a += ridge_epsilon(float(p.sum())) * np.eye(len(a))
    hat = x @ np.linalg.solve(a, x.T * p)
    return float(np.trace(hat))


@pytest.mark.parametrize("ridge", [1e-6, 0.05, 10.0])
def test_leverage_shares_out_the_exact_trace_of_the_hat_matrix(ridge):
    rng = np.random.default_rng(0)
    u = rng.normal(size=(120, 2))
    y = u + 0.1 * np.sin(u) + rng.normal(0, 0.01, u.shape)
    centers = u[:20]
    solver = WeightedSolver(u, y, centers, 2.0, "affine")
    p = rng.uniform(0.0, 1.0, len(u))
    start = Model(identity_model(2, "affine").linear, centers, 2.0, np.zeros((20, 2)))
    solver.solve(p, start, ridge)
    h = solver.leverage()
    assert h.shape == (120,) and (h >= 0).all()
    np.testing.assert_allclose(h.sum(), exact_hat_trace(solver, p, ridge), rtol=1e-6)
    np.testing.assert_allclose(h / h.sum(), p / p.sum(), rtol=1e-12)  # shared out by weight


def test_leverage_counts_every_unknown_without_a_ridge_and_only_the_affine_ones_under_a_strong_one():
    rng = np.random.default_rng(1)
    u = rng.normal(size=(200, 2))
    solver = WeightedSolver(u, u + 0.05, u[:10], 1.0, "affine")
    start = Model(identity_model(2, "affine").linear, u[:10], 1.0, np.zeros((10, 2)))
    ones = np.ones(len(u))
    solver.solve(ones, start, 1e-9)
    assert solver.leverage().sum() == pytest.approx(3 + 10, rel=1e-3)
    solver.solve(ones, start, 1e9)
    assert solver.leverage().sum() == pytest.approx(3, rel=1e-3)
