"""What every rigid registration method returns, and its transform as a value.

A rigid (or similarity) motion x -> s R x + t is a :class:`~reglib.KernelWarp` with an affine
linear part ``[s R | t]`` and no kernel centers, in the caller's own units (no normalization), so
its JSON form is the one of CONTRACTS.md and the client evaluates it unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._transforms import KernelWarp, LinearPart
from .._verdict import Reason

__all__ = ["RigidFit", "rigid_warp"]


@dataclass(frozen=True, eq=False)
class RigidFit:
    """The answer of one rigid method, before :func:`reglib.register_points` wraps it.

    Attributes
    ----------
    matrix : (D, D + 1) float64 ndarray
        ``[s R | t]``: a model point x goes to ``s R x + t`` (s = 1 for a rigid motion).
    n_iter : int
        Iterations the method ran.
    converged : bool
        The method stopped by its own tolerance, not by its iteration cap.
    reach : float
        Distance (caller's units) within which a moved model point counts as corresponding to
        its nearest target point; farther points get correspondence -1.
    reason : str or None
        Why the answer is not trusted although the method ran to its tolerance (one of
        :data:`reglib.registration._support.REGISTRATION_REASONS`; ``converged`` is then False), or None.
    """

    matrix: np.ndarray
    n_iter: int
    converged: bool
    reach: float
    reason: Reason | None = None


def rigid_warp(matrix: np.ndarray) -> KernelWarp:
    """The :class:`KernelWarp` of ``x -> matrix[:, :D] x + matrix[:, D]`` (no normalization, no centers)."""
    m = np.array(matrix, dtype=np.float64)
    d = m.shape[0]
    return KernelWarp(dim=d, src_mean=np.zeros(d), src_scale=1.0, dst_mean=np.zeros(d), dst_scale=1.0,
                      linear=LinearPart(kind="affine", matrix=m), beta=1.0, centers=np.zeros((0, d)),
                      weights=np.zeros((0, d)))
