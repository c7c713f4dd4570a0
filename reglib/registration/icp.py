"""Robust rigid ICP: point-to-point and point-to-plane, the robust functions of Babin et al. [1].

Each iteration pairs every (sampled) model point x_i, moved by the current motion, with its
nearest target point y_j (a k-d tree; memory O(N + M), never an N x M matrix), computes the
residual r_i, a scale sigma and weights w_i = w(|r_i| / sigma), and solves one weighted
least-squares step (iteratively re-weighted least squares, IRLS):

- ``"point_to_point"``: r_i = |x_i - y_j|; the step is the closed-form weighted rigid map of
  :mod:`reglib.registration.procrustes` (Umeyama's SVD or the SVD-free FA3R, ``solver``).
- ``"point_to_plane"``: r_i = n_j . (x_i - y_j) with the target normal n_j (given, or from the
  PCA of its ``k_normals`` nearest neighbours, computed only for target points that get matched);
  the step solves the 6 x 6 normal equations of the rotation linearized about the matched
  points' centroid (Chen & Medioni [2]; Low [3]) and applies it as an exact rotation.

Robust functions (``loss``), in terms of the scaled residual e = |r| / sigma and the tuning
constant k (``tuning``; its default per loss is in ``DEFAULT_TUNING``), as in Table I of [1]:

=================  ==========================================  ===========
loss               weight w(e)                                 default k
=================  ==========================================  ===========
``l2``             1                                           --
``l1``             1 / e                                       --
``huber``          1 if e <= k else k / e                      1.345
``cauchy``         1 / (1 + (e / k)^2)                         2.3849
``geman_mcclure``  1 / (1 + (e / k)^2)^2                       2.0
``welsch``         exp(-(e / k)^2)                             2.9846
``tukey``          (1 - (e / k)^2)^2 if e < k else 0           4.6851
``student``        (k + 1) / (k + e^2)   (k degrees of freedom)  3.0
``switchable``     1 if e <= k else 4 / (1 + (e / k)^2)^2      2.0
``trimmed``        1 for the ``trim_ratio`` smallest |r|, else 0  --
``max_distance``   1 if e <= k else 0 (or |r| <= max_distance)  3.0
=================  ==========================================  ===========

(Babin et al. write Geman-McClure and switchable constraint with k on the squared residual; ours
is theirs with k_theirs = k^2. ``trim_ratio=None`` is their "VarTrimmed": the kept fraction xi
minimizes the trimmed RMS over xi^3, as in Chetverikov et al.'s fractional RMSD [4].)

The scale sigma is ``scale`` when given (caller's units); otherwise it is re-estimated every
iteration from the residuals as a median absolute deviation about zero: sigma = median |r| / m,
with m the median of |r| for standard Gaussian noise (0.6745 for the signed point-to-plane
residual; 1.5382 for a 3-D and 1.1774 for a 2-D point-to-point distance), so sigma estimates the
per-coordinate noise when most pairs are right. At low overlap or with many outliers most pairs
are wrong, the median lies among them and the scale grows until the robust function rejects
nothing. So by default (``scale_quantile=None``) the share xi of right pairs is estimated every
iteration too, as VarTrimmed's xi of the point distances (below); when xi < 1/2 the MAD is taken
over the xi closest pairs only, and so are the query bounds below. (On the benchmark's 30-50 %
overlap cases with 0-50 % outliers, started at the true pose, the plain MAD drifted off to
point errors of 11-43 % of the extent in 5 of 6 cases; this scale stayed within 0.2 degrees and
0.2 % in the three 50 % cases, and slid by 4-18 % in the three 30 % ones.)

Initial alignment (``init``): ``"given"`` starts from the caller's pose; ``"centroid"`` from the
identity rotation with the centroids aligned; ``"search"`` (the default) adds a global start,
since plain local ICP fails beyond a few tens of degrees: a deterministic super-Fibonacci set of
``n_rotations`` rotations covering SO(3) [5] (in 2-D, equally spaced angles) up to
``init_max_angle``, each with the centroids aligned, and the caller's pose, all refined at once by
``init_iter`` trimmed point-to-point steps on ``init_points`` model samples against a target
sample (one batched tree query and one batched 3 x 3 SVD per step), scored by a smooth
largest-common-point-set measure mean(max(0, 1 - (d / tau)^2)), tau = twice the target
sample's spacing. The best ``init_keep`` go through more steps on more points; the winner starts
the robust ICP, except that the caller's pose is kept whenever it scores within ``init_margin``
of the winner (so scans that are roughly aligned stay so). The robust ICP's first, coarse stage
(below) then runs from the winner, from the caller's pose and from the runner-up, and the pose
that brings most of its sample within two target spacings goes on to the fine stage (after ten
trimmed steps the search's score can still prefer a wrong pose that the converged one does not:
on the benchmark's bunny at 50 % overlap with 25 % outliers the winner was 128 degrees off). A
hypothesis whose refinement drifted more than 20 degrees beyond ``init_max_angle`` cannot win: the
default range, 90 degrees, is a prior, and a deliberate one (a runner-up of the coarse stage
likewise). Searching all of SO(3) (``init_max_angle=180``) finds, for partial views of
near-symmetric shapes (boxes, faces, height fields seen from the front), a 180-degree
twin that covers more of the target than the true, partially overlapping pose, and the
largest-common-point-set score then prefers the twin.

Large sets: the robust ICP iterates on at most ``max_points`` model points (a random sample, from
``rng``), against the whole target; it first converges (to 10 x ``tolerance``) on a fifth of that
sample, where iterations are cheap, and then refines on the whole sample. k-d tree queries are
bounded, because a query far from the target visits many cells and is slow: after the first
iteration pairs farther apart than max(8 max(k, 3) sigma_d, 4 x the target's spacing) are
dropped (sigma_d the MAD scale of the point distances, over the same pairs as the residual
scale; the bound only shrinks), where every
redescending loss gives weight below 2 % anyway.

References
----------
.. [1] P. Babin, P. Giguere, F. Pomerleau, "Analysis of Robust Functions for Registration
       Algorithms", ICRA 2019. :doi:`10.1109/ICRA.2019.8793791`
.. [2] Y. Chen, G. Medioni, "Object modelling by registration of multiple range images", Image
       and Vision Computing 10(3), 1992. :doi:`10.1016/0262-8856(92)90066-C`
.. [3] K.-L. Low, "Linear Least-Squares Optimization for Point-to-Plane ICP Surface
       Registration", Tech. Rep. TR04-004, UNC Chapel Hill, 2004.
.. [4] D. Chetverikov, D. Stepanov, P. Krsek, "Robust Euclidean alignment of 3D point sets: the
       trimmed iterative closest point algorithm", Image and Vision Computing 23(3), 2005.
       :doi:`10.1016/j.imavis.2004.05.007`
.. [5] M. Alexa, "Super-Fibonacci Spirals: Fast, Low-Discrepancy Sampling of SO(3)", CVPR 2022.
       :doi:`10.1109/CVPR52688.2022.00811`
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any, Literal

import numpy as np
from scipy import ndimage, stats
from scipy.spatial import cKDTree

from .._validation import as_choice, check_int, check_range
from ..errors import InputError
from .normals import LazyNormals
from .procrustes import _fa3r_rotation
from .rigid import RigidFit

__all__ = ["DEFAULT_TUNING", "LOSSES", "VARIANTS", "ICPLoopOptions", "ICPOptions", "icp_register"]

Variant = Literal["point_to_point", "point_to_plane"]
Loss = Literal["l2", "l1", "huber", "cauchy", "geman_mcclure", "welsch", "tukey", "student",
               "switchable", "trimmed", "max_distance"]
Solver = Literal["svd", "fa3r"]
Init = Literal["given", "centroid", "search"]

VARIANTS: tuple[Variant, ...] = ("point_to_point", "point_to_plane")
LOSSES: tuple[Loss, ...] = ("l2", "l1", "huber", "cauchy", "geman_mcclure", "welsch", "tukey", "student",
                            "switchable", "trimmed", "max_distance")
SOLVERS: tuple[Solver, ...] = ("svd", "fa3r")
INITS: tuple[Init, ...] = ("given", "centroid", "search")

DEFAULT_TUNING: dict[str, float] = {"l2": 1.0, "l1": 1.0, "huber": 1.345, "cauchy": 2.3849,
                                    "geman_mcclure": 2.0, "welsch": 2.9846, "tukey": 4.6851,
                                    "student": 3.0, "switchable": 2.0, "trimmed": 1.0,
                                    "max_distance": 3.0}

# median of |r| for standard Gaussian noise: signed scalar residual, 2-D and 3-D distances
_MEDIAN_ABS = {1: 0.6744897501960817, 2: 1.1774100225154747, 3: 1.5381722544550522}
_SIGMA_FLOOR = 1e-9   # relative to the model's RMS radius
_COARSE_FRACTION = 5  # the first fine-stage pass runs on max_points / 5 samples
_BOUND_FACTOR = 8.0   # queries reach 8 max(k, 3) point-distance scales (module docstring)
_ANGLE_SLACK = 20.0   # degrees a hypothesis may drift beyond init_max_angle and still win
_RUNNERS = 1         # runners-up of the search (besides the caller's pose) the coarse stage also tries
_ADAPTIVE_BELOW = 0.5  # scale_quantile=None: the MAD of the VarTrimmed share when it is below this
_PSI = 1.533751168755204288118041  # Alexa's super-Fibonacci constant (psi^4 = psi + 4)


@dataclass(frozen=True, slots=True, kw_only=True)
class ICPLoopOptions:
    """The options ``"icp"`` and ``"icp-hmrf"`` share: the residual, the iteration and the start.

    Parameters
    ----------
    variant : {"point_to_plane", "point_to_point"}
        Residual: distance to the target point, or to the target point's tangent plane.
    max_iter : int
        ICP iterations at most (<= 1000).
    tolerance : float
        Stop when the RMS motion of the model samples in one iteration is below ``tolerance``
        times the model's RMS radius.
    k_normals : int
        Neighbours for the PCA normals of the target (point-to-plane without ``target_normals``).
    solver : {"svd", "fa3r"}
        Closed-form point-to-point step: Umeyama's SVD or FA3R (3-D only).
    init : {"search", "centroid", "given"}
        Initial alignment (module docstring).
    n_rotations : int
        Rotations sampled over all of SO(3) (2-D: over the full turn) by ``init="search"``.
    init_max_angle : float
        Degrees; rotation hypotheses beyond this angle from the identity are skipped.
    init_points, init_iter, init_keep : int
        Model samples, trimmed steps per hypothesis, and hypotheses kept for the second round of
        the search.
    init_margin : float
        The caller's pose wins the search when its score is at least (1 - init_margin) times the
        best.
    """

    variant: Variant = "point_to_plane"
    max_iter: int = 50
    tolerance: float = 1e-5
    k_normals: int = 10
    solver: Solver = "svd"
    init: Init = "search"
    n_rotations: int = 512
    init_max_angle: float = 90.0
    init_points: int = 200
    init_iter: int = 10
    init_keep: int = 6
    init_margin: float = 0.05

    def _check_loop(self) -> None:
        """Validation of the shared fields (each subclass's ``__post_init__`` calls it)."""
        as_choice(self.variant, "variant", VARIANTS)
        as_choice(self.solver, "solver", SOLVERS)
        as_choice(self.init, "init", INITS)
        check_range("tolerance", self.tolerance, 0, low_open=True)
        check_range("init_max_angle", self.init_max_angle, 0, 180)
        check_range("init_margin", self.init_margin, 0, 1, high_open=True)
        # Upper bounds keep every request finite in time and memory.
        for name, low, high in (("max_iter", 1, 1000), ("k_normals", 3, 100), ("n_rotations", 1, 4096),
                                ("init_points", 10, 5000), ("init_iter", 1, 200), ("init_keep", 1, 64)):
            check_int(name, getattr(self, name), low, high)

    def loop_fields(self) -> dict[str, Any]:
        """The shared fields and their values (to build one kind of options from the other)."""
        return {f.name: getattr(self, f.name) for f in fields(ICPLoopOptions)}


@dataclass(frozen=True, slots=True, kw_only=True)
class ICPOptions(ICPLoopOptions):
    """Options of ``register_points(method="icp")``; lengths are in the caller's units.

    Parameters
    ----------
    loss : str
        Robust function, one of ``LOSSES`` (module docstring for the formulas).
    tuning : float, optional
        Tuning constant k of the loss in units of the scale (``DEFAULT_TUNING[loss]`` when None).
    scale : float, optional
        Residual scale sigma (caller's units); None re-estimates it every iteration by the MAD.
    scale_quantile : float, optional
        The estimated scale is the ``scale_quantile`` quantile of |r| over that of unit Gaussian
        noise: 0.5 is the MAD (module docstring); lower values tolerate more pairs from outside
        the overlap (at most 1 - q of them), at some cost in efficiency. In [0.05, 0.95]. None
        (default): the MAD, taken over the VarTrimmed share of the pairs when that share is below
        one half (module docstring).
    trim_ratio : float, optional
        Fraction of pairs kept by ``loss="trimmed"``, in (0, 1]; None chooses it every iteration
        (Babin's VarTrimmed, Chetverikov's xi minimizing RMS(xi) / xi^3 over [0.2, 1]).
    max_distance : float, optional
        Pairs farther apart than this (caller's units) are dropped, for every loss; with
        ``loss="max_distance"`` it is the threshold (``tuning`` times sigma when None).
    normal_angle : float
        Degrees; with ``model_normals`` given, pairs whose normals differ by more (sign ignored)
        are dropped.
    max_points : int
        Model points the robust ICP iterates on at most (a random sample beyond it).
    variant, max_iter, tolerance, k_normals, solver, init, n_rotations, init_max_angle, init_points, \
init_iter, init_keep, init_margin
        The residual, the iteration and the initial alignment: :class:`ICPLoopOptions`.
    """

    loss: Loss = "cauchy"
    tuning: float | None = None
    scale: float | None = None
    scale_quantile: float | None = None
    trim_ratio: float | None = 0.7
    max_distance: float | None = None
    normal_angle: float = 60.0
    max_points: int = 10000

    def __post_init__(self) -> None:
        self._check_loop()
        as_choice(self.loss, "loss", LOSSES)
        if self.tuning is not None:
            check_range("tuning", self.tuning, 0, low_open=True)
        if self.scale is not None:
            check_range("scale", self.scale, 0, low_open=True)
        if self.trim_ratio is not None:
            check_range("trim_ratio", self.trim_ratio, 0, 1, low_open=True)
        if self.max_distance is not None:
            check_range("max_distance", self.max_distance, 0, low_open=True)
        if self.scale_quantile is not None:
            check_range("scale_quantile", self.scale_quantile, 0.05, 0.95)
        check_range("normal_angle", self.normal_angle, 0, 90, low_open=True)
        check_int("max_points", self.max_points, 10, 1_000_000)


# ----------------------------------------------------------------------------- robust weights

def _trim_fraction(r_abs: np.ndarray) -> float:
    """Chetverikov's xi in [0.2, 1] minimizing sqrt(mean of the xi smallest r^2) / xi^3."""
    r2 = np.sort(r_abs * r_abs)
    n = len(r2)
    xi = np.linspace(0.2, 1.0, 33)
    counts = np.maximum((xi * n).astype(int), 1)
    rms = np.sqrt(np.cumsum(r2)[counts - 1] / counts)
    return float(xi[int(np.argmin(rms / xi**3))])


def robust_weights(r_abs: np.ndarray, sigma: float, loss: str, k: float, *,
                   trim_ratio: float | None = None, max_distance: float | None = None) -> np.ndarray:
    """IRLS weights w(|r| / sigma) of ``loss`` with tuning ``k`` (module table); (K,) in [0, inf)."""
    if loss == "l2":
        return np.ones_like(r_abs)
    if loss == "trimmed":
        if len(r_abs) == 0:
            return np.ones_like(r_abs)
        ratio = _trim_fraction(r_abs) if trim_ratio is None else trim_ratio
        keep = max(int(np.ceil(ratio * len(r_abs))), 1)
        thr = np.partition(r_abs, keep - 1)[keep - 1]
        return (r_abs <= thr).astype(np.float64)
    if loss == "max_distance" and max_distance is not None:
        return (r_abs <= max_distance).astype(np.float64)
    e = r_abs / sigma
    if loss == "l1":
        return 1.0 / np.maximum(e, 1e-6)
    if loss == "huber":
        return np.where(e <= k, 1.0, k / np.maximum(e, 1e-300))
    q = (e / k) ** 2
    if loss == "cauchy":
        return 1.0 / (1.0 + q)
    if loss == "geman_mcclure":
        return 1.0 / (1.0 + q) ** 2
    if loss == "welsch":
        return np.exp(-q)
    if loss == "tukey":
        return np.where(q < 1.0, (1.0 - q) ** 2, 0.0)
    if loss == "student":
        return (k + 1.0) / (k + e * e)
    if loss == "switchable":
        return np.where(q <= 1.0, 1.0, 4.0 / (1.0 + q) ** 2)
    if loss == "max_distance":
        return (e <= k).astype(np.float64)
    raise InputError(f"`loss` must be one of {list(LOSSES)}, got {loss!r}")


def mad_scale(r_abs: np.ndarray, dof: int, quantile: float = 0.5) -> float:
    """sigma = q-quantile of |r| / the same quantile for unit Gaussian noise (q = 1/2: the MAD); 0 for none."""
    if len(r_abs) == 0:
        return 0.0
    if quantile == 0.5:
        return float(np.median(r_abs)) / _MEDIAN_ABS[dof]
    return float(np.quantile(r_abs, quantile)) / float(stats.chi.ppf(quantile, dof))


# ----------------------------------------------------------------------------- small geometry

def _rotation_from_vector(omega: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation exp([omega]_x) (3-D) or by angle omega[0] (2-D)."""
    if len(omega) == 1:
        c, s = np.cos(omega[0]), np.sin(omega[0])
        return np.array([[c, -s], [s, c]])
    theta = float(np.linalg.norm(omega))
    kx = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]])
    if theta < 1e-12:
        return np.eye(3) + kx
    return np.eye(3) + np.sin(theta) / theta * kx + (1.0 - np.cos(theta)) / theta**2 * (kx @ kx)


def _proper_polar(h: np.ndarray) -> np.ndarray:
    """Batched nearest rotations to (..., D, D) cross-covariances (Umeyama's sign fix)."""
    u, _, vt = np.linalg.svd(h)
    d = np.where(np.linalg.det(u @ vt) < 0.0, -1.0, 1.0)
    u[..., :, -1] *= d[..., None]
    return u @ vt


def rotation_hypotheses(dim: int, n: int, max_angle_deg: float) -> np.ndarray:
    """Deterministic rotations (K, D, D) covering SO(D) up to ``max_angle_deg`` from the identity.

    3-D: Alexa's super-Fibonacci spiral of ``n`` unit quaternions; 2-D: ``n`` equally spaced
    angles. The identity is always first.
    """
    limit = np.deg2rad(max_angle_deg) + 1e-12
    if dim == 2:
        ang = 2.0 * np.pi * np.arange(1, n) / n
        ang = np.where(ang > np.pi, ang - 2.0 * np.pi, ang)
        ang = ang[np.abs(ang) <= limit]
        c, s = np.cos(ang), np.sin(ang)
        rots = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
        return np.concatenate([np.eye(2)[None], rots])
    s = np.arange(n) + 0.5
    r = np.sqrt(s / n)
    big_r = np.sqrt(1.0 - s / n)
    alpha = 2.0 * np.pi * s / np.sqrt(2.0)
    beta = 2.0 * np.pi * s / _PSI
    q = np.stack([r * np.sin(alpha), r * np.cos(alpha), big_r * np.sin(beta), big_r * np.cos(beta)], 1)
    w, x, y, z = q[:, 3], q[:, 0], q[:, 1], q[:, 2]
    angle = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    keep = (angle <= limit) & (angle > 1e-9)
    w, x, y, z = w[keep], x[keep], y[keep], z[keep]
    rots = np.empty((len(w), 3, 3))
    rots[:, 0, 0] = 1 - 2 * (y * y + z * z)
    rots[:, 0, 1] = 2 * (x * y - z * w)
    rots[:, 0, 2] = 2 * (x * z + y * w)
    rots[:, 1, 0] = 2 * (x * y + z * w)
    rots[:, 1, 1] = 1 - 2 * (x * x + z * z)
    rots[:, 1, 2] = 2 * (y * z - x * w)
    rots[:, 2, 0] = 2 * (x * z - y * w)
    rots[:, 2, 1] = 2 * (y * z + x * w)
    rots[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return np.concatenate([np.eye(3)[None], rots])


def _angle(rots: np.ndarray) -> np.ndarray:
    """Rotation angles in degrees of (H, D, D) rotations."""
    dim = rots.shape[-1]
    tr = np.trace(rots, axis1=-2, axis2=-1)
    cos = (tr - 1.0) / 2.0 if dim == 3 else tr / 2.0
    return np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0)))


def _sample(n: int, k: int, rng: np.random.Generator) -> np.ndarray:
    if n <= k:
        return np.arange(n)
    return np.sort(rng.choice(n, size=k, replace=False))


def _spacing(tree: cKDTree, points: np.ndarray, rng: np.random.Generator) -> float:
    """Median distance from a point of ``points`` to its nearest other point (sampled)."""
    probe = points[_sample(len(points), 1000, rng)]
    d, _ = tree.query(probe, k=2)
    d = np.asarray(d)[:, 1]
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 0.0


# ----------------------------------------------------------------------------- global start

class VoxelNearest:
    """Approximate nearest target point by a voxel distance transform (for the global search).

    The target's bounding box, grown by half its size on every side, is cut into ``cells`` voxels along
    its longest side; every voxel stores the index of a target point in the nearest occupied voxel
    (``scipy.ndimage.distance_transform_edt``). A lookup is O(1) and exact to about a voxel
    diagonal, also for points far from the target, where a k-d tree query is slow.
    """

    def __init__(self, target: np.ndarray, cells: int = 64) -> None:
        lo, hi = target.min(0), target.max(0)
        size = np.maximum(hi - lo, 1e-12 * max(float(np.max(hi - lo)), 1e-300))
        self.lo = lo - 0.5 * size
        self.voxel = float(np.max(2.0 * size)) / cells
        self.shape = np.maximum(np.ceil(2.0 * size / self.voxel).astype(int), 1)
        cell = self._cells(target)
        flat = np.ravel_multi_index(cell.T, self.shape)
        owner = np.full(int(np.prod(self.shape)), -1, dtype=np.int64)
        owner[flat] = np.arange(len(target))
        empty = (owner < 0).reshape(self.shape)
        idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        nearest_cell = np.ravel_multi_index(tuple(idx.reshape(len(self.shape), -1)), self.shape)
        self.nearest = owner[nearest_cell]
        self.target = target

    def _cells(self, x: np.ndarray) -> np.ndarray:
        c = np.floor((x - self.lo) / self.voxel).astype(np.int64)
        return np.clip(c, 0, self.shape - 1)

    def query(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices) of the approximate nearest target points of ``x`` (K, D)."""
        j = self.nearest[np.ravel_multi_index(self._cells(x).T, self.shape)]
        return np.linalg.norm(x - self.target[j], axis=1), j


def batch_trimmed_icp(src: np.ndarray, target: np.ndarray, lookup: VoxelNearest | cKDTree, rots: np.ndarray,
                      trans: np.ndarray, n_iter: int, keep: float, bound: float = np.inf,
                      floor: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run ``n_iter`` trimmed point-to-point ICP steps from every pose (rots[h], trans[h]) at once.

    ``lookup`` answers nearest-target queries: a :class:`VoxelNearest` (all poses in one lookup),
    or a k-d tree queried per pose with a bound that starts at ``bound`` and then follows 1.5
    times the pose's trimming threshold (at least ``floor``): pairs beyond the threshold are
    trimmed anyway, and bounded queries are fast. Returns the refined rotations (H, D, D),
    translations (H, D) and the final nearest-target distances (H, S) of the ``src`` samples
    (inf beyond the bound).
    """
    h, s, dim = len(rots), len(src), src.shape[1]
    n_keep = min(max(int(keep * s), dim + 1), s)
    m = len(target)
    bounds = np.full(h, bound)

    def distances(r: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.einsum("hij,sj->hsi", r, src) + t[:, None, :]
        if isinstance(lookup, VoxelNearest):
            d, j = lookup.query(x.reshape(-1, dim))
            return d.reshape(h, s), j.reshape(h, s)
        d = np.empty((h, s))
        j = np.empty((h, s), dtype=np.int64)
        for k in range(h):
            dk, jk = lookup.query(x[k], distance_upper_bound=bounds[k])
            d[k], j[k] = dk, np.minimum(jk, m - 1)
        return d, j

    for _ in range(n_iter):
        d, j = distances(rots, trans)
        thr = np.partition(d, n_keep - 1, axis=1)[:, n_keep - 1]
        w = ((d <= thr[:, None]) & np.isfinite(d)).astype(np.float64)
        total = w.sum(1)
        ok = total >= dim + 1
        total = np.maximum(total, 1.0)
        y = target[j]                                               # (H, S, D)
        mu_x = w @ src / total[:, None]
        mu_y = np.einsum("hs,hsd->hd", w, y) / total[:, None]
        xc = src[None, :, :] - mu_x[:, None, :]
        cov = np.einsum("hs,hsi,hsj->hij", w, y - mu_y[:, None, :], xc)
        new_rots = _proper_polar(cov)
        new_trans = mu_y - np.einsum("hij,hj->hi", new_rots, mu_x)
        rots = np.where(ok[:, None, None], new_rots, rots)
        trans = np.where(ok[:, None], new_trans, trans)
        bounds = np.where(np.isfinite(thr), np.clip(1.5 * thr, floor, bound), bounds)
    d, _ = distances(rots, trans)
    return rots, trans, d


@dataclass(frozen=True)
class Start:
    """The initial pose and what the search learnt about the scale of the problem."""

    matrix: np.ndarray
    bound: float            # distance within which the right pairs lie after the start (inf: unknown)
    others: tuple[np.ndarray, ...] = ()  # runner-up poses of the search, tried by the coarse stage too


def initial_alignment(model: np.ndarray, target: np.ndarray, tree: cKDTree, opts: ICPOptions,
                      rng: np.random.Generator) -> Start:
    """The starting ``[R | t]`` (D, D + 1) chosen by ``opts.init`` (module docstring)."""
    dim = model.shape[1]
    eye = np.c_[np.eye(dim), np.zeros(dim)]
    if opts.init == "given":
        return Start(eye, np.inf)
    mu_m = model.mean(0)
    mu_t = target.mean(0)
    if opts.init == "centroid":
        return Start(np.c_[np.eye(dim), mu_t - mu_m], np.inf)
    rots = rotation_hypotheses(dim, opts.n_rotations, opts.init_max_angle)
    trans = mu_t[None, :] - np.einsum("hij,j->hi", rots, mu_m)
    # the caller's pose (identity, no shift) as its own hypothesis, first
    rots = np.concatenate([np.eye(dim)[None], rots])
    trans = np.concatenate([np.zeros((1, dim)), trans])
    t_small = target[_sample(len(target), 20 * opts.init_points, rng)]
    voxels = VoxelNearest(t_small)
    t_tree = cKDTree(t_small)
    src = model[_sample(len(model), opts.init_points, rng)]
    rots, trans, _ = batch_trimmed_icp(src, t_small, voxels, rots, trans, opts.init_iter, 0.5)
    # score with exact distances, queries bounded by tau (beyond it a pair scores 0 anyway)
    tau = 2.0 * max(_spacing(t_tree, t_small, rng), voxels.voxel)
    x = (np.einsum("hij,sj->hsi", rots, src) + trans[:, None, :]).reshape(-1, dim)
    d = np.asarray(t_tree.query(x, distance_upper_bound=tau)[0]).reshape(len(rots), -1)
    score = np.maximum(0.0, 1.0 - (d / tau) ** 2).mean(1)
    # a pose that drifted beyond the searched range is not a candidate (the prior of init_max_angle)
    score = np.where(_angle(rots) <= opts.init_max_angle + _ANGLE_SLACK, score, -1.0)
    order = np.argsort(-score, kind="stable")
    best = [int(i) for i in order[:opts.init_keep]]
    if 0 not in best:
        best.append(0)
    # second round: more points, the whole target (k-d tree, bounded queries), more steps
    src2 = model[_sample(len(model), 3 * opts.init_points, rng)]
    spacing = _spacing(tree, target, rng)
    bound = tau
    rots2, trans2, d2 = batch_trimmed_icp(src2, target, tree, rots[best], trans[best], opts.init_iter, 0.5,
                                          bound=bound, floor=2.0 * spacing)
    tau2 = 2.0 * spacing
    score2 = np.maximum(0.0, 1.0 - (d2 / tau2) ** 2).mean(1)
    score2 = np.where(_angle(rots2) <= opts.init_max_angle + _ANGLE_SLACK, score2, -1.0)
    win = int(np.argmax(score2))
    given = best.index(0)
    if score2[given] >= (1.0 - opts.init_margin) * score2[win]:
        win = given
    ranked = [int(i) for i in np.argsort(-score2, kind="stable") if i != win and score2[i] >= 0.0]
    runners = ([given] if given != win else []) + [i for i in ranked if i != given][:_RUNNERS]
    return Start(np.c_[rots2[win], trans2[win]], bound, tuple(np.c_[rots2[i], trans2[i]] for i in runners))


# ----------------------------------------------------------------------------- robust ICP

def _plane_step(x: np.ndarray, y: np.ndarray, n: np.ndarray,
                w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted linearized point-to-plane step: (rotation, centre c, shift) with x -> R (x - c) + c + shift."""
    dim = x.shape[1]
    total = float(w.sum())
    c = w @ x / total
    p = x - c
    if dim == 3:
        a_rot = np.cross(p, n)
    else:
        a_rot = (p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0])[:, None]
    a = np.concatenate([a_rot, n], axis=1)
    b = ((y - x) * n).sum(1)
    aw = a * w[:, None]
    lhs = aw.T @ a
    rhs = aw.T @ b
    lhs[np.diag_indices_from(lhs)] += 1e-12 * max(float(np.trace(lhs)), 1e-300)
    try:
        xi = np.linalg.solve(lhs, rhs)
    except np.linalg.LinAlgError:
        xi = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    n_rot = a_rot.shape[1]
    return _rotation_from_vector(xi[:n_rot]), c, xi[n_rot:]


def _point_step(src: np.ndarray, dst: np.ndarray, w: np.ndarray, solver: str) -> np.ndarray:
    total = float(w.sum())
    mu_s = w @ src / total
    mu_d = w @ dst / total
    h = (w[:, None] * (dst - mu_d)).T @ (src - mu_s)
    rot = _fa3r_rotation(h) if solver == "fa3r" else _proper_polar(h)
    return np.c_[rot, mu_d - rot @ mu_s]


def robust_icp(model: np.ndarray, target: np.ndarray, tree: cKDTree, normals: LazyNormals | None,
               start: Start, opts: ICPOptions, *, model_normals: np.ndarray | None = None,
               radius: float = 1.0, spacing: float = 0.0) -> tuple[np.ndarray, int, bool, float]:
    """IRLS ICP of ``model`` (the iterated sample) from ``start``; returns (matrix, n_iter, converged, sigma).

    Queries are bounded (module docstring): by ``opts.max_distance``, by ``start.bound`` in the
    first iteration, and then by max(8 max(k, 3) sigma_d, 4 ``spacing``) with sigma_d the MAD
    scale of the previous iteration's point distances.
    """
    dim = model.shape[1]
    rot, t = start.matrix[:, :dim].copy(), start.matrix[:, dim].copy()
    k = DEFAULT_TUNING[opts.loss] if opts.tuning is None else float(opts.tuning)
    plane = opts.variant == "point_to_plane"
    if plane and normals is None:
        raise ValueError("point-to-plane ICP needs the target normals")
    dof = 1 if plane else dim
    user_bound = np.inf if opts.max_distance is None else float(opts.max_distance)
    bound = min(user_bound, start.bound)
    reach_factor = _BOUND_FACTOR * max(k, 3.0)
    cos_max = np.cos(np.deg2rad(opts.normal_angle))
    floor = _SIGMA_FLOOR * radius
    sigma = floor
    prev: np.ndarray | None = None
    converged = False
    it = 0
    for it in range(1, opts.max_iter + 1):
        x = model @ rot.T + t
        if prev is not None and np.sqrt(np.mean(np.sum((x - prev) ** 2, 1))) < opts.tolerance * radius:
            converged = True
            it -= 1
            break
        prev = x
        d, j = tree.query(x, distance_upper_bound=bound)
        valid = np.isfinite(d)
        if model_normals is not None:
            tn = normals[np.minimum(j, len(target) - 1)] if normals is not None else None
            if tn is not None:
                mn = model_normals @ rot.T
                valid &= np.abs((mn * tn).sum(1)) >= cos_max
        if valid.sum() < dim + 1:
            break
        dv = d[valid]
        # the pairs the scale is estimated from: all, or (scale_quantile=None) the VarTrimmed share
        # when it is below one half, so that the median of all would fall among the outliers
        core: slice | np.ndarray = slice(None)
        if opts.scale_quantile is None:
            xi = _trim_fraction(dv)
            if xi < _ADAPTIVE_BELOW:
                core = dv <= np.quantile(dv, xi)
        bound = min(bound, user_bound, max(reach_factor * mad_scale(dv[core], dim), 4.0 * spacing))
        j = j[valid]
        xv = x[valid]
        y = target[j]
        if plane and normals is not None:
            n = normals[j]
            r_abs = np.abs(((xv - y) * n).sum(1))
        else:
            r_abs = dv
        if opts.scale is not None:
            sigma = float(opts.scale)
        else:
            sigma = max(mad_scale(r_abs[core], dof, 0.5 if opts.scale_quantile is None else opts.scale_quantile), floor)
        w = robust_weights(r_abs, sigma, opts.loss, k, trim_ratio=opts.trim_ratio, max_distance=opts.max_distance)
        if not np.isfinite(w).all() or float(w.sum()) <= 0.0 or (w > 0).sum() < dim + 1:
            break
        if plane and normals is not None:
            step, c, shift = _plane_step(xv, y, n, w)
            t = step @ (t - c) + c + shift
            rot = step @ rot
        else:
            m = _point_step(model[valid], y, w, opts.solver)
            rot, t = m[:, :dim], m[:, dim]
    return np.c_[rot, t], it, converged, sigma


def icp_register(model: np.ndarray, target: np.ndarray, opts: ICPOptions, rng: np.random.Generator, *,
                 model_normals: np.ndarray | None = None, target_normals: np.ndarray | None = None,
                 _start: Start | None = None, _tree: cKDTree | None = None) -> RigidFit:
    """Rigidly register ``model`` onto ``target`` by robust ICP (module docstring).

    Parameters
    ----------
    model, target : (N, D), (M, D) float64 ndarray
        Validated finite point sets, (x, y[, z]) rows, D in {2, 3}, in the caller's units.
    opts : ICPOptions
        Variant, robust function, scale, iteration limits, solver and initial alignment.
    rng : numpy.random.Generator
        Draws the point samples; the same seed gives the same answer.
    model_normals : (N, D) ndarray, optional
        Normals of the model; when given, pairs whose normals disagree by more than
        ``opts.normal_angle`` are dropped.
    target_normals : (M, D) ndarray, optional
        Normals of the target for point-to-plane (estimated from ``opts.k_normals`` neighbours
        when omitted).

    Returns
    -------
    RigidFit
        ``[R | t]`` (D, D + 1) taking model points onto the target, the robust ICP's iterations,
        whether it met ``opts.tolerance``, and the reach 3 sigma (at least the target's spacing).

    Raises
    ------
    InputError
        ``solver="fa3r"`` with 2-D points; normals of the wrong shape.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> target = rng.uniform(-1.0, 1.0, size=(500, 3)) * [1.0, 0.6, 0.3]
    >>> c, s = np.cos(0.3), np.sin(0.3)
    >>> rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    >>> model = (target - [0.1, 0.0, 0.2]) @ rot     # target = rot @ model + [0.1, 0, 0.2]
    >>> fit = icp_register(model, target, ICPOptions(variant="point_to_point"), rng)
    >>> bool(np.allclose(fit.matrix, np.c_[rot, [0.1, 0.0, 0.2]], atol=1e-6))
    True
    """
    dim = model.shape[1]
    if opts.solver == "fa3r" and dim != 3:
        raise InputError(f"`solver`='fa3r' needs 3-D points, got D = {dim}")
    for name, nrm, pts in (("model_normals", model_normals, model), ("target_normals", target_normals, target)):
        if nrm is not None and np.shape(nrm) != pts.shape:
            raise InputError(f"`{name}` must have shape {pts.shape}, got {np.shape(nrm)}")
    tree = cKDTree(target) if _tree is None else _tree
    radius = float(np.sqrt(np.mean(np.sum((model - model.mean(0)) ** 2, 1)))) or 1.0
    start = initial_alignment(model, target, tree, opts, rng) if _start is None else _start
    need_normals = opts.variant == "point_to_plane" or model_normals is not None
    normals = LazyNormals(target, tree, opts.k_normals, target_normals) if need_normals else None
    mn_all = None
    if model_normals is not None:
        mn_all = np.asarray(model_normals, dtype=np.float64)
        mn_all = mn_all / np.maximum(np.linalg.norm(mn_all, axis=1, keepdims=True), 1e-300)
    spacing = _spacing(tree, target, rng)
    # coarse to fine: converge on a small sample first (cheap iterations), then on max_points
    idx = _sample(len(model), opts.max_points, rng)
    n_small = max(opts.max_points // _COARSE_FRACTION, 10)
    n_iter = 0
    if len(idx) > 2 * n_small or start.others:
        small = idx[_sample(len(idx), n_small, rng)] if len(idx) > 2 * n_small else idx
        coarse = replace(opts, tolerance=opts.tolerance * 10.0)
        # the search's winner and its runners-up (the caller's pose first) each converge on the
        # small sample; the one that brings most of it within two target spacings goes on
        best_score = -1.0
        for cand in (start.matrix, *start.others):
            m0, it0, _, _ = robust_icp(model[small], target, tree, normals, Start(cand, start.bound), coarse,
                                       model_normals=None if mn_all is None else mn_all[small],
                                       radius=radius, spacing=spacing)
            tau = 2.0 * spacing if spacing > 0 else radius * 1e-3
            d = np.asarray(tree.query(model[small] @ m0[:, :dim].T + m0[:, dim], distance_upper_bound=tau)[0])
            score = float(np.maximum(0.0, 1.0 - (d / tau) ** 2).mean())
            if best_score >= 0.0 and _angle(m0[None, :, :dim])[0] > opts.init_max_angle + _ANGLE_SLACK:
                continue                                            # a runner-up beyond the prior
            if score > best_score:
                best_score, best_m, n_iter = score, m0, it0
        start = Start(best_m, start.bound)
    matrix, n_fine, converged, sigma = robust_icp(model[idx], target, tree, normals, start, opts,
                                                  model_normals=None if mn_all is None else mn_all[idx],
                                                  radius=radius, spacing=spacing)
    n_iter += n_fine
    reach = max(3.0 * sigma, spacing)
    return RigidFit(matrix=matrix, n_iter=n_iter, converged=converged, reach=reach)
