"""Nearest-neighbour descriptor matching with Lowe's ratio test and the mutual check.

Both descriptor matchers of the package reduce to the same selection (:func:`select_matches`):
for each descriptor of image a its nearest neighbour in b is kept when

- the **ratio test** passes: its distance is below ``ratio`` times the distance to the second
  nearest (Lowe [1]_; ``ratio=1`` keeps every nearest neighbour), and
- with ``mutual=True``, the **mutual check** passes: a's descriptor is in turn the nearest
  neighbour of that descriptor of b.

They differ in how the neighbours are found:

- :func:`match_descriptors`: Euclidean distance by OpenCV's brute-force matcher (any float
  descriptors; SIFT's RootSIFT, :mod:`reglib.features._sift`). Deterministic, unlike an
  unseeded FLANN index.
- :func:`match_unit_descriptors`: for unit-norm descriptors (the multimodal ones), the distance
  sqrt(2 - 2 cos) from one matrix product of cosine similarities; exact ties resolve to the
  lower index.

Matches are returned as two index arrays sorted by the row of a.

References
----------
.. [1] D. G. Lowe, "Distinctive Image Features from Scale-Invariant Keypoints", IJCV 60, 2004.
       :doi:`10.1023/B:VISI.0000029664.99615.94`
"""
from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["match_descriptors", "match_unit_descriptors", "select_matches"]


def select_matches(nearest: np.ndarray, first: np.ndarray, second: np.ndarray, *, ratio: float,
                   back: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Matches from a to b that pass the ratio test and, given ``back``, the mutual check.

    Trusted input, does not validate.

    Parameters
    ----------
    nearest : (Ka,) int ndarray
        Row of b nearest to each row of a; -1 where there is none.
    first, second : (Ka,) float ndarray
        Distances to the nearest and to the second-nearest row of b. The test ``first < ratio *
        second`` is computed in their dtype; it fails where ``second`` is NaN (no second
        neighbour to compare with) and passes where it is inf.
    ratio : float
        Lowe's ratio; 1.0 or more skips the test (every nearest neighbour is kept).
    back : (Kb,) int ndarray, optional
        Row of a nearest to each row of b: keep only pairs that are each other's nearest
        neighbour. None: no mutual check.

    Returns
    -------
    idx_a, idx_b : (N,) intp ndarray
        Matched rows of a and b, ``idx_a`` ascending.

    Examples
    --------
    Row 0's nearest is clearly nearer than its second; row 1's is not; row 2's passes the ratio
    test but row 1 of b prefers row 1 of a:

    >>> nearest = np.array([0, 1, 1])
    >>> first, second = np.array([0.1, 0.5, 0.2]), np.array([0.9, 0.55, 0.8])
    >>> select_matches(nearest, first, second, ratio=0.8)
    (array([0, 2]), array([0, 1]))
    >>> select_matches(nearest, first, second, ratio=0.8, back=np.array([0, 1]))
    (array([0]), array([0]))
    """
    keep = nearest >= 0
    if ratio < 1.0:
        keep &= first < ratio * second
    if back is not None:
        keep &= back[np.maximum(nearest, 0)] == np.arange(len(nearest))
    idx_a = np.flatnonzero(keep).astype(np.intp)
    return idx_a, nearest[idx_a].astype(np.intp)


def _empty() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(0, np.intp), np.zeros(0, np.intp)


def match_descriptors(desc_a: np.ndarray, desc_b: np.ndarray, *, ratio: float = 0.8,
                      mutual: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour matches from a to b in Euclidean distance, ratio test, optional mutual check.

    Parameters
    ----------
    desc_a, desc_b : (Ka, F), (Kb, F) float32 ndarray
    ratio : float
        Keep a match when its distance is below ``ratio`` times the second-nearest one (1.0
        keeps every nearest neighbour; below 1, a b of one row gives no matches: there is no
        second neighbour to compare with).
    mutual : bool
        Keep only pairs that are each other's nearest neighbour.

    Returns
    -------
    idx_a, idx_b : (N,) intp ndarray
        Matched rows of ``desc_a`` and ``desc_b``, sorted by ``idx_a``.

    Examples
    --------
    >>> a = np.array([[0, 0], [10, 0], [5, 0.1]], np.float32)
    >>> b = np.array([[0.2, 0], [10.1, 0], [5.5, 0]], np.float32)
    >>> match_descriptors(a, b)
    (array([0, 1, 2]), array([0, 1, 2]))
    >>> match_descriptors(a, b[:2], ratio=1.0, mutual=True)   # row 2 of a is nobody's nearest
    (array([0, 1]), array([0, 1]))
    """
    if len(desc_a) == 0 or len(desc_b) == 0:
        return _empty()
    bf = cv2.BFMatcher(cv2.NORM_L2)
    k = 2 if len(desc_b) >= 2 else 1
    knn = bf.knnMatch(desc_a, desc_b, k=k)
    n = len(knn)
    nearest = np.full(n, -1, np.intp)
    first, second = np.full(n, np.nan), np.full(n, np.nan)  # float64: the ratio test in double precision
    for i, row in enumerate(knn):
        if row:
            nearest[i], first[i] = row[0].trainIdx, row[0].distance
            if len(row) >= 2:
                second[i] = row[1].distance
    back = None
    if mutual:
        back = np.full(len(desc_b), -1, np.intp)
        for mt in bf.match(desc_b, desc_a):
            back[mt.queryIdx] = mt.trainIdx
    return select_matches(nearest, first, second, ratio=ratio, back=back)


def match_unit_descriptors(desc_a: np.ndarray, desc_b: np.ndarray, *, ratio: float = 0.95,
                           mutual: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour matches of unit-norm descriptors by cosine similarity, ratio test, mutual check.

    The distance of two unit vectors is sqrt(2 - 2 cos), so one matrix product ``a @ b.T`` (in
    float32) gives every distance; the nearest neighbour is the most similar row (exact ties: the
    lower index). Brute force, deterministic; memory O(Ka * Kb).

    Parameters
    ----------
    desc_a, desc_b : (Ka, F), (Kb, F) float32 ndarray
        Rows of unit L2 norm (not checked: other rows give a ranking by dot product).
    ratio : float
        Lowe's ratio test on the distances; 1.0 keeps every nearest neighbour (so does a b of one
        row, whose second distance counts as infinite).
    mutual : bool
        Keep only pairs that are each other's nearest neighbour.

    Returns
    -------
    idx_a, idx_b : (N,) intp ndarray
        Matched rows of ``desc_a`` and ``desc_b``, sorted by ``idx_a``.

    Raises
    ------
    InputError
        When the descriptors are not (Ka, F) and (Kb, F), or ``ratio`` is not in (0, 1].

    Examples
    --------
    >>> d = np.eye(3, dtype=np.float32)
    >>> match_unit_descriptors(d, d[[2, 0, 1]])
    (array([0, 1, 2]), array([1, 2, 0]))
    """
    a = np.asarray(desc_a, np.float32)
    b = np.asarray(desc_b, np.float32)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InputError(f"`desc_a` and `desc_b` must be (Ka, F) and (Kb, F), got {a.shape} and {b.shape}")
    if not 0.0 < ratio <= 1.0:
        raise InputError(f"`ratio` must be in (0, 1], got {ratio}")
    if len(a) == 0 or len(b) == 0:
        return _empty()
    return _match_unit(a, b, ratio, mutual)


def _match_unit(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool) -> tuple[np.ndarray, np.ndarray]:
    """:func:`match_unit_descriptors` on trusted, non-empty float32 input."""
    sim = a @ b.T
    nearest, first, second = _nearest_by_similarity(sim)
    back = np.argmax(sim, axis=0) if mutual else None
    return select_matches(nearest, first, second, ratio=ratio, back=back)


def _nearest_by_similarity(sim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best index, best and second-best distance sqrt(2 - 2 cos) per row of a cosine-similarity matrix."""
    n = sim.shape[1]
    if n >= 2:
        top2 = np.argpartition(-sim, 1, axis=1)[:, :2]
        s2 = np.take_along_axis(sim, top2, axis=1)
        swap = s2[:, 1] > s2[:, 0]
        best = np.where(swap, top2[:, 1], top2[:, 0])
        # exact ties resolve to the lower index, as a stable argmax would
        best = np.where(s2[:, 0] == s2[:, 1], top2.min(axis=1), best)
        d1 = np.sqrt(np.maximum(2.0 - 2.0 * s2.max(axis=1), 0.0))
        d2 = np.sqrt(np.maximum(2.0 - 2.0 * s2.min(axis=1), 0.0))
    else:
        best = np.zeros(sim.shape[0], np.intp)
        d1 = np.sqrt(np.maximum(2.0 - 2.0 * sim[:, 0], 0.0))
        d2 = np.full(sim.shape[0], np.inf)
    return best, d1, d2
