"""The feature start of rigid 3-D registration (``init="features"``): FPFH matches + RANSAC.

No prior on the pose: rotations over the whole sphere are found by local surface evidence.

1. Both sets are cut into cubes of side v (``feature_voxel``; by default 1/60 of the larger
   bounding-box diagonal), one centroid per cube (:func:`reglib.features.voxel_downsample`);
   cubes that points scattered through the volume explain are dropped (its ``drop_scatter``:
   outliers would make most of the cubes and spoil their neighbours' descriptors), with
   PCA normals of 30 neighbours and FPFH descriptors of radius 5 v (:mod:`reglib.features._fpfh`),
   and matched by mutual nearest descriptor (all nearest neighbours when fewer than 10 are mutual).
2. ``feature_estimator="ransac"`` (the default): RANSAC on triples of matches (``feature_iter``
   of them, drawn from ``rng``): a triple whose three edges do not have the same lengths in both
   sets (to 10 %) is dropped, as in Open3D's edge checker; the others give a rigid map by
   Umeyama's SVD (batched) and count the matches it brings within 1.5 v. ``"l2e"``: this
   library's L2E (:func:`reglib.robust.filter_matches` with ``linear="rigid"`` and no kernel)
   gives one hypothesis instead; on the global benchmark's tuning seeds it succeeds less often
   (from the identity, its annealing does not reach every rotation).
3. The best ``_KEEP`` distinct hypotheses are refined by least squares on their inliers (twice),
   then ranked by the share of the downsampled model that lands within 1.5 v of the downsampled
   target. The first starts the robust ICP; the others and the caller's pose go with it
   (:attr:`~reglib.registration._start.Start.others`), and the ICP's coarse stage keeps the
   converged pose that brings most of the model near the target: twins of symmetric objects are
   decided by the feature evidence and the refined overlap, not by a limit on the angle.

:class:`FeatureEvidence` keeps what the matches said (their number and the inliers of the
winner), which :func:`reglib.registration._icp.icp_register` uses to say when support is too small.

Points are (N, 3) rows (x, y, z) in the caller's units; trusted input.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .._geometry import nearest_rotation
from ..features import fpfh, match_features, oriented_normals, voxel_downsample
from ..robust import L2EOptions, filter_matches
from ._icp_options import ICPLoopOptions
from ._start import Start, initial_alignment

__all__ = ["Described", "FeatureEvidence", "Prepared", "choose_start", "feature_start", "l2e_rigid", "ransac_rigid"]

VOXEL_SHARE = 1.0 / 60.0   # default voxel: this share of the larger bounding-box diagonal
_RADIUS = 5.0              # FPFH radius in voxels
_NORMAL_K = 30
_INLIER = 1.5              # match inlier distance in voxels
_EDGE = 0.9                # edge-length similarity of a RANSAC triple
_KEEP = 4                  # hypotheses refined and handed on
_MIN_MUTUAL = 10
_CELLS = 1 << 18          # match x map distances computed at once (2 MB)
_EXAMINE = 8               # the best 8 x keep triples are refined, at most


@dataclass(frozen=True, eq=False)
class Described:
    """One set as the feature start sees it, kept so that the registration the other way round
    (``verify``) reuses it: the same voxel gives the same cubes and descriptors.

    Attributes
    ----------
    voxel : float
        The voxel side v (caller's units).
    points : (K, 3) ndarray
        The centroids of the cubes kept.
    surface : (N,) bool ndarray
        The set's points in those cubes.
    desc : (K, 33) ndarray or None
        Their FPFH descriptors; None until computed (too few cubes: never).
    """

    voxel: float
    points: np.ndarray
    surface: np.ndarray
    desc: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Prepared:
    """What a feature start computed on a pair of sets: each set's cubes and descriptors, and their
    mutual matches (None: fewer than ``_MIN_MUTUAL``, or not computed). Mutual nearest neighbours
    are the same pairs either way round, so the backward run of ``verify`` takes them swapped."""

    model: Described
    target: Described
    mutual: tuple[np.ndarray, np.ndarray] | None = None

    def swapped(self) -> Prepared:
        """The same, target first (matches sorted by their new model side)."""
        mutual = None
        if self.mutual is not None:
            order = np.argsort(self.mutual[1], kind="stable")
            mutual = (self.mutual[1][order], self.mutual[0][order])
        return Prepared(self.target, self.model, mutual)


def _describe(points: np.ndarray, voxel: float, known: Described | None) -> Described:
    """The cubes of ``points`` (``known`` when it describes as many points with the same voxel)."""
    if known is not None and known.voxel == voxel and len(known.surface) == len(points):
        return known
    cubes, surface = voxel_downsample(points, voxel, drop_scatter=True, return_mask=True)
    return Described(voxel=voxel, points=cubes, surface=surface)


def _with_descriptors(d: Described) -> Described:
    if d.desc is not None:
        return d
    return replace(d, desc=fpfh(d.points, oriented_normals(d.points, _NORMAL_K), _RADIUS * d.voxel))


@dataclass(frozen=True, eq=False)
class FeatureEvidence:
    """What the feature matches said about the pose.

    Attributes
    ----------
    n_matches : int
        Putative matches RANSAC ran on.
    voxel : float
        The voxel side v (caller's units).
    src, dst : (K, 3) ndarray
        The matched downsampled points, model and target side.
    best_inliers : int
        Inliers of the best RANSAC hypothesis (0: no hypothesis, the start fell back).
    surface : (N,) bool ndarray, optional
        The model points in the cubes the downsampling kept (not scattered through the
        volume: :func:`reglib.features.voxel_downsample`'s ``drop_scatter``).
    prepared : Prepared or None
        The sets as described (with descriptors once computed) and their mutual matches.
    """

    n_matches: int
    voxel: float
    src: np.ndarray
    dst: np.ndarray
    best_inliers: int = 0
    surface: np.ndarray | None = None
    prepared: Prepared | None = None

    def kept(self, matrix: np.ndarray) -> float:
        """Share of the best hypothesis' inliers that ``matrix`` keeps (may exceed 1)."""
        return self.inliers(matrix) / max(self.best_inliers, 1)

    def inliers(self, matrix: np.ndarray) -> int:
        """Matches that ``matrix`` ([R | t]) brings within 1.5 v."""
        if not self.n_matches:
            return 0
        moved = self.src @ matrix[:, :3].T + matrix[:, 3]
        return int((np.linalg.norm(moved - self.dst, axis=1) < _INLIER * self.voxel).sum())


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid maps (H, 3, 3), (H, 3) taking each triple of a (H, S, 3) onto b by least squares."""
    ma, mb = a.mean(1), b.mean(1)
    cov = np.einsum("hsi,hsj->hij", b - mb[:, None], a - ma[:, None])
    rot = nearest_rotation(cov)
    return rot, mb - np.einsum("hij,hj->hi", rot, ma)


def _inlier_counts(src: np.ndarray, dst: np.ndarray, rot: np.ndarray, t: np.ndarray,
                   threshold: float) -> np.ndarray:
    """For each map (rot[h], t[h]) the matches it brings within ``threshold``, by matrix products.

    With S, D the matches about their centroids and tau = R c_src + t - c_dst, the squared
    distance |R S_k + tau - D_k|^2 = |S_k|^2 + |D_k|^2 + |tau|^2 + 2 (R^T tau) . S_k
    - 2 tau . D_k - 2 vec(D_k S_k^T) . vec(R): one (H, 17) x (17, K) product per chunk of maps
    (the two constant terms as columns), in chunks small enough to stay in the cache.
    """
    cs, cd = src.mean(0), dst.mean(0)
    s, d = src - cs, dst - cd
    base = (s * s).sum(1) + (d * d).sum(1)
    feats = np.concatenate([s, d, (d[:, :, None] * s[:, None, :]).reshape(-1, 9), base[:, None],
                            np.ones((len(s), 1))], 1)                                  # (K, 17)
    tau = rot @ cs + t - cd                                                            # (H, 3)
    u = np.einsum("hji,hj->hi", rot, tau)                                              # R^T tau
    coef = np.concatenate([2.0 * u, -2.0 * tau, -2.0 * rot.reshape(-1, 9), np.ones((len(rot), 1)),
                           (tau * tau).sum(1)[:, None]], 1)                            # (H, 17)
    limit = threshold * threshold
    counts = np.empty(len(rot), dtype=np.int64)
    step = max(1, _CELLS // max(len(src), 1))
    for h in range(0, len(rot), step):
        counts[h:h + step] = np.count_nonzero(coef[h:h + step] @ feats.T < limit, axis=1)
    return counts


def ransac_rigid(src: np.ndarray, dst: np.ndarray, threshold: float, n_iter: int, rng: np.random.Generator,
                 keep: int = _KEEP) -> list[tuple[np.ndarray, int]]:
    """RANSAC on triples of 3-D matches ``src[i] -> dst[i]``: the best ``keep`` rigid maps.

    Parameters
    ----------
    src, dst : (K, 3) ndarray
        Putative matches, K >= 3.
    threshold : float
        A match is an inlier of a map when it lands within this distance.
    n_iter : int
        Triples drawn.
    rng : numpy.random.Generator
        Draws them.
    keep : int
        Distinct hypotheses returned (refined by least squares on their inliers, twice).

    Returns
    -------
    list of ((3, 4) ndarray, int)
        ``[R | t]`` and its inlier count, most inliers first; empty when no triple passes the
        edge check.
    """
    k = len(src)
    if k < 3:
        return []
    tri = rng.integers(0, k, size=(n_iter, 3))
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    a, b = src[tri], dst[tri]                                     # (H, 3, 3)
    ea = np.linalg.norm(a - a[:, [1, 2, 0]], axis=2)
    eb = np.linalg.norm(b - b[:, [1, 2, 0]], axis=2)
    ok = ((np.minimum(ea, eb) >= _EDGE * np.maximum(ea, eb)) & (np.maximum(ea, eb) > 0)).all(1)
    a, b = a[ok], b[ok]
    if not len(a):
        return []
    rot, t = _kabsch(a, b)
    counts = _inlier_counts(src, dst, rot, t, threshold)
    out: list[tuple[np.ndarray, int]] = []
    seen: list[np.ndarray] = []
    for h in np.argsort(-counts, kind="stable")[:_EXAMINE * keep]:
        if len(out) >= keep or counts[h] < 3:
            break
        m = np.c_[rot[h], t[h]]
        for _ in range(2):                                        # least squares on the inliers
            inl = np.linalg.norm(src @ m[:, :3].T + m[:, 3] - dst, axis=1) < threshold
            if inl.sum() < 3:
                break
            r1, t1 = _kabsch(src[inl][None], dst[inl][None])
            m = np.c_[r1[0], t1[0]]
        # a hypothesis that refines onto one already kept is the same one
        if any(np.abs(m[:, :3] - q[:, :3]).max() < 0.05 and np.linalg.norm(m[:, 3] - q[:, 3]) < threshold
               for q in seen):
            continue
        seen.append(m)
        n_in = int((np.linalg.norm(src @ m[:, :3].T + m[:, 3] - dst, axis=1) < threshold).sum())
        out.append((m, n_in))
    out.sort(key=lambda item: -item[1])
    return out


def l2e_rigid(src: np.ndarray, dst: np.ndarray, threshold: float,
              rng: np.random.Generator) -> list[tuple[np.ndarray, int]]:
    """This library's L2E with a rigid linear part and no kernel on the matches: one hypothesis."""
    if len(src) < 3:
        return []
    res = filter_matches(src, dst, options=L2EOptions(linear="rigid", n_centers=0, max_centers=0), rng=rng)
    basis = res.transform(np.vstack([np.zeros(3), np.eye(3)]))
    m = np.c_[(basis[1:] - basis[0]).T, basis[0]]
    m[:, :3] = nearest_rotation(m[:, :3])
    n_in = int((np.linalg.norm(src @ m[:, :3].T + m[:, 3] - dst, axis=1) < threshold).sum())
    return [(m, n_in)]


def feature_start(model: np.ndarray, target: np.ndarray, opts: ICPLoopOptions, rng: np.random.Generator, *,
                  prepared: Prepared | None = None) -> tuple[Start | None, FeatureEvidence | None]:
    """The feature start of ``model`` onto ``target`` (module docstring), and what it found.

    The start is None when the sets are not 3-D, or too few matches or no consistent triple are
    found; the caller then falls back to the rotation search. The evidence is None for 2-D
    sets; without a start it holds the model's surface points only (no matches). ``prepared``:
    what an earlier feature start on these sets computed (:attr:`FeatureEvidence.prepared`), reused
    where its voxel is this one's.
    """
    if model.shape[1] != 3:
        return None, None
    diag = max(float(np.linalg.norm(np.ptp(model, 0))), float(np.linalg.norm(np.ptp(target, 0))))
    voxel = opts.feature_voxel if opts.feature_voxel is not None else VOXEL_SHARE * diag
    if not voxel > 0:
        return None, None
    dm = _describe(model, voxel, None if prepared is None else prepared.model)
    dt = _describe(target, voxel, None if prepared is None else prepared.target)
    pm, pt, surface = dm.points, dt.points, dm.surface
    none = FeatureEvidence(n_matches=0, voxel=voxel, src=np.zeros((0, 3)), dst=np.zeros((0, 3)), surface=surface,
                           prepared=Prepared(dm, dt))
    if len(pm) < _NORMAL_K or len(pt) < _NORMAL_K:
        return None, none
    dm, dt = _with_descriptors(dm), _with_descriptors(dt)
    fm, ft = np.asarray(dm.desc), np.asarray(dt.desc)
    known = None if prepared is None or prepared.model is not dm or prepared.target is not dt else prepared.mutual
    ia, ib = known if known is not None else match_features(fm, ft, mutual=True)
    mutual = (ia, ib) if len(ia) >= _MIN_MUTUAL else None
    if mutual is None:
        ia, ib = match_features(fm, ft, mutual=False)
    src, dst = pm[ia], pt[ib]
    if opts.feature_estimator == "l2e":
        hyps = l2e_rigid(src, dst, _INLIER * voxel, rng)
    else:
        hyps = ransac_rigid(src, dst, _INLIER * voxel, opts.feature_iter, rng)
    if not hyps:
        return None, replace(none, prepared=Prepared(dm, dt, mutual))
    evidence = FeatureEvidence(n_matches=len(ia), voxel=voxel, src=src, dst=dst, best_inliers=hyps[0][1],
                               surface=surface, prepared=Prepared(dm, dt, mutual))
    t_tree = cKDTree(pt)
    fitness = []
    for m, _ in hyps:
        d, _ = t_tree.query(pm @ m[:, :3].T + m[:, 3], distance_upper_bound=_INLIER * voxel)
        fitness.append(float(np.isfinite(d).mean()))
    order = np.argsort(-np.asarray(fitness), kind="stable")
    mats = [hyps[i][0] for i in order]
    eye = np.c_[np.eye(3), np.zeros(3)]
    return Start(mats[0], 3.0 * voxel, (*mats[1:], eye)), evidence


def choose_start(model: np.ndarray, target: np.ndarray, tree: cKDTree, opts: ICPLoopOptions,
                 rng: np.random.Generator, *, prepared: Prepared | None = None
                 ) -> tuple[Start, FeatureEvidence | None]:
    """The start of ``opts.init``: the feature start (with its evidence) or :func:`initial_alignment`'s.

    ``init="features"`` falls back to the rotation search (``init="search"``) where the feature
    start finds nothing (2-D sets, too few matches); the evidence then has no matches
    (``best_inliers == 0``), or is None (2-D sets, other starts). ``prepared``: as for :func:`feature_start`.
    """
    evidence = None
    if opts.init == "features":
        start, evidence = feature_start(model, target, opts, rng, prepared=prepared)
        if start is not None:
            return start, evidence
        opts = replace(opts, init="search")
    return initial_alignment(model, target, tree, opts, rng), evidence
