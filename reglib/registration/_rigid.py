"""What every rigid registration method returns, and its transform as a value.

A rigid, similarity or affine map x -> A x + t (A = R, s R or a general matrix) is a
:class:`~reglib.KernelWarp` with an affine linear part ``[A | t]`` and no kernel centers, in the
caller's own units (means zero, scales 1: CONTRACTS.md's "Rigid transforms"), so its JSON form is
the one of CONTRACTS.md, the client evaluates it unchanged and a user reads the translation off
it. :func:`caller_matrix` brings a map fitted in normalized coordinates (the CPD family's) to that
form; :func:`homogeneous` gives the (D + 1, D + 1) matrix of ``Registration.matrix``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._transforms import KernelWarp, LinearPart
from .._verdict import Reason

__all__ = ["RigidFit", "caller_matrix", "homogeneous", "rigid_warp"]


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


def caller_matrix(warp: KernelWarp) -> np.ndarray:
    """``[A | t]`` (D, D + 1) of ``warp``, an affine map between normalized frames, in the caller's units.

    ``warp`` maps x to ``dst_mean + dst_scale (a (x - src_mean) / src_scale + b)`` with ``[a | b]`` its
    linear part and no kernel; that is ``A x + t`` with ``A = (dst_scale / src_scale) a`` and
    ``t = dst_mean + dst_scale b - A src_mean``.
    """
    if warp.linear is None or warp.linear.kind != "affine" or warp.n_centers:
        raise ValueError("caller_matrix takes an affine warp without kernel centers")
    d = warp.dim
    lin = warp.linear.matrix
    a = (warp.dst_scale / warp.src_scale) * lin[:, :d]
    t = warp.dst_mean + warp.dst_scale * lin[:, d] - a @ warp.src_mean
    return np.c_[a, t]


def homogeneous(matrix: np.ndarray) -> np.ndarray:
    """The (D + 1, D + 1) homogeneous form of ``[A | t]`` (D, D + 1): ``[[A, t], [0, 1]]``."""
    d = matrix.shape[0]
    out = np.eye(d + 1)
    out[:d] = matrix
    return out
