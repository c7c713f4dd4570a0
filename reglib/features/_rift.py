"""RIFT-style modality-robust features: phase-congruency corners, maximum-index-map descriptors,
and their matching under one global rotation hypothesis.

For pairs taken by different sensors (visible / infrared / SAR / depth / map, MR / PET / CT, colour
fundus / angiogram), where intensities are related by an unknown nonlinear, even non-monotonic map
and SIFT's gradient histograms do not survive. The design follows RIFT [1]_:

1. **Normalize**: any real dtype (uint8, uint16, float) and RGB become a grey float image in
   [0, 1] (:func:`~reglib.features.normalize_intensity`, a robust percentile stretch), then a
   working copy whose longer side is ``max_side`` (resized down, or up for small images, so that
   the filter wavelengths and the descriptor patch have one meaning in every image).
2. **Detect** on phase congruency (Kovesi [2]_ [3]_; :mod:`reglib.features._phase`), which is
   invariant to contrast and brightness: local maxima of the minimum moment (corners; maxima of
   the maximum moment, edges, fill up when there are too few), spread evenly over an 8 x 8 grid
   of cells, refined to sub-pixel by a parabola (:func:`~reglib.features.subpixel_peaks`).
3. **Describe** with the maximum index map (MIM): per pixel, the index of the log-Gabor
   orientation with the largest amplitude summed over scales. Around each keypoint a
   ``n_grid x n_grid`` grid of cells covering ``patch`` working pixels holds a Gaussian-weighted
   histogram of MIM values (``n_orient`` bins), each pixel counted with the square root of its
   phase-congruency edge measure: ``n_grid**2 * n_orient`` numbers, square-rooted, unit L2 norm.
4. **Rotation**: rotating an image by ``pi / n_orient`` shifts every MIM index by one (the index
   ring of [1]_). With ``rotation_invariant=True`` each keypoint is also described on the grid
   rotated by each multiple of ``pi / n_orient`` (12 hypotheses over the full circle for the
   default 6 orientations) with the bins shifted cyclically to match: ``descriptors`` holds the
   ``n_rotations`` blocks side by side, block 0 upright. :func:`match_multimodal` picks the one
   global rotation hypothesis with the most mutual nearest-neighbour matches (the relative
   orientation of two images is one number; a per-keypoint dominant orientation is unreliable
   across modalities) and matches block 0 of a against that block of b. Rotations between
   hypotheses (at most 15 degrees away) are tolerated by the coarse grid.
5. **Scale**: each image is worked at the same longer side, so pairs covering the same field of
   view at different resolutions agree; further scale change is met by a second pyramid level
   (1 / sqrt(2) the side) matched together with the first, and tolerated in between by the four
   log-Gabor scales summed into the MIM and the coarse grid.

Keypoints of two sensors do not repeat to the pixel: :func:`~reglib.features.refine_matches`
moves each match's end in b by correlating dense structure fields (:mod:`reglib.features._structure`).

Coordinates: (x, y) pixels of the image given, x the column, the centre of the top-left pixel
(0, 0). A point x' of the working copy (scale s = W'/W) is x = (x' + 0.5) / s - 0.5 in the image.

References
----------
.. [1] J. Li, Q. Hu, M. Ai, "RIFT: Multi-modal Image Matching Based on Radiation-variation
       Insensitive Feature Transform", IEEE TIP 29, 2020. :doi:`10.1109/TIP.2019.2959244`
.. [2] P. Kovesi, "Image Features from Phase Congruency", Videre 1(3), 1999.
.. [3] P. Kovesi, "Phase Congruency Detects Corners and Edges", DICTA 2003.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from .._validation import check_int, check_range
from ..errors import InputError
from ._keypoints import Features
from ._matching import _match_unit
from ._normalize import NormalizedImage, _check_image, _normalized, _working_copy, check_mask
from ._peaks import subpixel_peaks
from ._phase import phase_congruency

__all__ = ["N_ROTATIONS", "detect_multimodal", "match_multimodal"]

N_ROTATIONS = 12  # rotation hypotheses with the default 6 orientations: one per pi / 6
_MIN_SIDE = 16  # smaller images give no keypoints
_LEVEL_SCALE = 2 ** -0.5  # pyramid step: the descriptor's scale tolerance is about +-20 %
_POOL_SIGMA = 0.35  # Gaussian pooling of a descriptor cell, in cell sides
_BORDER = 4  # working pixels at the border where no keypoint is taken (reflected padding)

def _select(response: np.ndarray, allowed: np.ndarray, n_max: int, nms_radius: int,
            threshold: float, n_cells: int) -> np.ndarray:
    """(K, 2) int (row, col) of local maxima of ``response``, spread over an n x n grid of cells.

    Maxima are ranked within their cell; all cells' best come first, then all second best, ...,
    each round by response (a deterministic round robin), cut at ``n_max``.
    """
    size = 2 * nms_radius + 1
    peak = (response == ndimage.maximum_filter(response, size=size, mode="constant")) & allowed
    peak &= response > threshold
    rows, cols = np.nonzero(peak)
    if len(rows) == 0:
        return np.zeros((0, 2), np.intp)
    val = response[rows, cols]
    h, w = response.shape
    cell = (rows * n_cells // h) * n_cells + cols * n_cells // w
    order = np.lexsort((cols, rows, -val, cell))  # by cell, then strongest first (ties by position)
    cell_sorted = cell[order]
    first = np.searchsorted(cell_sorted, cell_sorted, side="left")
    rank = np.empty(len(order), np.intp)
    rank[order] = np.arange(len(order)) - first
    pick = np.lexsort((cols, rows, -val, rank))[:n_max]
    return np.stack([rows[pick], cols[pick]], axis=1)


def _mim_channels(amplitude: np.ndarray, edge: np.ndarray, sigma: float) -> np.ndarray:
    """(O, H, W) pooled maximum index map: channel o is the Gaussian-weighted (``sigma``) sum, near
    each pixel, of sqrt(edge measure) over the pixels whose strongest log-Gabor orientation is o.

    RIFT counts every pixel alike; weighting by sqrt of the phase-congruency edge measure (itself
    contrast-invariant, in [0, 1]) keeps flat, noisy regions, whose MIM is random, from filling the
    histograms.
    """
    n_orient = amplitude.shape[0]
    mim = np.argmax(amplitude, axis=0)
    weight = np.sqrt(edge)
    out = np.empty(amplitude.shape, np.float32)
    for o in range(n_orient):
        out[o] = cv2.GaussianBlur(np.where(mim == o, weight, 0.0).astype(np.float32), (0, 0), sigma,
                                  borderType=cv2.BORDER_CONSTANT)
    return out


def _describe(channels: np.ndarray, points: np.ndarray, *, patch: float, n_grid: int,
              n_rotations: int) -> np.ndarray:
    """(K, n_rotations * n_grid**2 * O) float32: MIM histograms on grids rotated by 2 pi r / R.

    Block r samples the grid rotated by phi_r = 2 pi r / n_rotations (x' = R(phi) g, x right, y
    down) and takes bin k from channel (k - shift_r) mod O, shift_r = phi_r / (pi / O): a structure
    whose MIM is k in image a has MIM k - shift_r in a copy rotated by phi_r.
    """
    n_orient = channels.shape[0]
    k = len(points)
    cell = patch / n_grid
    g = (np.arange(n_grid) - (n_grid - 1) / 2.0) * cell
    gx, gy = np.meshgrid(g, g)  # row-major cells: (row i, col j)
    offsets = np.stack([gx.ravel(), gy.ravel()], axis=1)  # (G, 2) as (x, y)
    phi = 2.0 * np.pi * np.arange(n_rotations) / n_rotations
    cos, sin = np.cos(phi)[:, None], np.sin(phi)[:, None]
    ox = cos * offsets[None, :, 0] - sin * offsets[None, :, 1]  # (R, G)
    oy = sin * offsets[None, :, 0] + cos * offsets[None, :, 1]
    map_x = (points[:, 0][:, None, None] + ox[None]).reshape(k * n_rotations, -1).astype(np.float32)
    map_y = (points[:, 1][:, None, None] + oy[None]).reshape(k * n_rotations, -1).astype(np.float32)
    samples = np.empty((n_orient, k * n_rotations, map_x.shape[1]), np.float32)
    for o in range(n_orient):
        samples[o] = cv2.remap(channels[o], map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=0.0)
    grid = samples.reshape(n_orient, k, n_rotations, -1)  # (O, K, R, G)
    shifts = np.rint(phi / (np.pi / n_orient)).astype(np.intp)  # (R,)
    bins = (np.arange(n_orient)[None, :] - shifts[:, None]) % n_orient  # (R, O): channel of bin k
    desc = np.empty((k, n_rotations, grid.shape[3], n_orient), np.float32)
    for r in range(n_rotations):  # bin b of block r is channel bins[r, b]
        desc[:, r] = grid[bins[r], :, r, :].transpose(1, 2, 0)
    blocks = np.sqrt(np.maximum(desc.reshape(k, n_rotations, -1), 0.0))  # Hellinger-like: tames dominant bins
    blocks /= np.maximum(np.linalg.norm(blocks, axis=2, keepdims=True), 1e-12)
    return blocks.reshape(k, -1).astype(np.float32)


def detect_multimodal(image: np.ndarray | NormalizedImage, *, mask: np.ndarray | None = None, max_keypoints: int = 1500,
                      max_side: int = 512, patch: float = 96.0, n_grid: int = 6, n_levels: int = 2,
                      rotation_invariant: bool = True, edge_share: float = 0.0) -> Features:
    """Phase-congruency keypoints with rotation-hypothesis MIM descriptors (RIFT-style).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) ndarray, or NormalizedImage
        Any real dtype (uint8, uint16, float), normalized by
        :func:`~reglib.features.normalize_intensity`; or that normalized copy, made once for
        several steps (:class:`~reglib.features.NormalizedImage`).
    mask : (H, W) array_like, optional
        Keypoints are only taken where it is nonzero.
    max_keypoints : int
        At most this many keypoints over all levels (level l gets a share in proportion to its
        area), spread over an 8 x 8 grid of cells. Matching cost grows with its square.
    max_side : int
        Longer side of the first level's working copy, pixels; images are resized down or up to it
        (so that the filter wavelengths and ``patch`` mean the same in every image).
    patch : float
        Side of the described square in working pixels (RIFT's J = 96).
    n_grid : int
        Cells per side of the descriptor grid (RIFT's 6 x 6).
    n_levels : int
        Pyramid levels, each 1 / sqrt(2) the side of the one before, detected and described
        alike and matched together: scale changes up to about 1.4 (and beyond with more levels).
    rotation_invariant : bool
        Also describe on the 11 grids rotated by multiples of 30 degrees with the MIM ring shifted
        (see the module notes); False gives the upright block only.
    edge_share : float
        Share of the keypoints taken from maxima of the edge measure (maximum moment) rather than
        the corner measure (minimum moment). RIFT takes both; corners are better localized, so by
        default edges only fill up when an image has too few corners.

    Returns
    -------
    Features
        ``points`` (K, 2) float64 (x, y) in ``image``'s pixels (centre of the top-left pixel
        (0, 0)); ``sizes`` the patch side in those pixels; ``angles`` 0; ``descriptors``
        (K, R * n_grid**2 * 6) float32, R = 12 rotation blocks (1 without rotation invariance),
        each of unit L2 norm. Rows are ordered strongest first per level, levels interleaved.

    Raises
    ------
    InputError
        When ``image`` is not a real (H, W) or (H, W, 3) array, ``mask`` has another shape, or
        an option is out of range.

    Examples
    --------
    >>> from skimage.data import camera
    >>> f = detect_multimodal(camera(), max_keypoints=300)
    >>> f.points.shape, f.descriptors.shape
    ((300, 2), (300, 2592))
    """
    arr = image if isinstance(image, NormalizedImage) else _check_image(image)
    check_int("max_keypoints", max_keypoints, 1)
    check_int("max_side", max_side, 32, 8192)
    check_int("n_grid", n_grid, 1, 16)
    check_int("n_levels", n_levels, 1, 6)
    check_range("patch", patch, 4.0, float(max_side))
    check_range("edge_share", edge_share, 0.0, 1.0)
    h, w = arr.shape[:2]
    m = check_mask(mask, (h, w), "mask")
    n_orient = 6
    n_rot = 2 * n_orient if rotation_invariant else 1
    dim = n_rot * n_grid * n_grid * n_orient
    if min(h, w) < _MIN_SIDE or (m is not None and not m.any()):
        return Features.empty(dim)
    gray = _normalized(arr)
    parts = []
    shares = np.array([_LEVEL_SCALE ** (2 * lv) for lv in range(n_levels)])
    quotas = np.maximum(1, np.round(max_keypoints * shares / shares.sum()).astype(int))
    for lv in range(n_levels):
        side = max(_MIN_SIDE, round(max_side * _LEVEL_SCALE ** lv))
        parts.append(_detect_level(gray, m, side, int(quotas[lv]), patch=patch, n_grid=n_grid,
                                   n_rotations=n_rot, edge_share=edge_share, n_orient=n_orient))
    pts = np.concatenate([q[0] for q in parts])
    if len(pts) == 0:
        return Features.empty(dim)
    # interleave the levels by relative rank, so that the first rows hold each level's strongest
    key = np.concatenate([np.arange(len(q[0])) / max(len(q[0]), 1) for q in parts])
    order = np.argsort(key, kind="stable")
    desc = np.concatenate([q[1] for q in parts])[order]
    sizes = np.concatenate([np.full(len(q[0]), q[2]) for q in parts])[order]
    return Features(pts[order], sizes, np.zeros(len(pts)), desc)


def _detect_level(gray: np.ndarray, mask: np.ndarray | None, side: int, n_keypoints: int, *, patch: float,
                  n_grid: int, n_rotations: int, edge_share: float,
                  n_orient: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Keypoints (in ``gray``'s pixels), descriptors and patch size of one pyramid level."""
    work, sx, sy = _working_copy(gray, side)
    pc = phase_congruency(work, n_orient=n_orient)
    wh, ww = work.shape
    allowed = np.zeros((wh, ww), bool)
    allowed[_BORDER:wh - _BORDER, _BORDER:ww - _BORDER] = True
    if mask is not None:
        allowed &= cv2.resize(mask.astype(np.uint8), (ww, wh), interpolation=cv2.INTER_NEAREST) > 0
    n_edge = round(n_keypoints * edge_share)
    corners = _select(pc.corner, allowed, n_keypoints - n_edge, 2, 1e-3, 8)
    edges = np.zeros((0, 2), np.intp)
    if len(corners) < n_keypoints:
        near = np.zeros_like(allowed)
        near[corners[:, 0], corners[:, 1]] = True  # no edge point within 2 px of a corner
        taken = allowed & ~ndimage.binary_dilation(near, iterations=2)
        edges = _select(pc.edge, taken, n_keypoints - len(corners), 2, 1e-3, 8)
    xy = np.concatenate([subpixel_peaks(pc.corner, corners), subpixel_peaks(pc.edge, edges)])
    size = patch / np.sqrt(sx * sy)
    if len(xy) == 0:
        return np.zeros((0, 2)), np.zeros((0, n_rotations * n_grid * n_grid * n_orient), np.float32), size
    channels = _mim_channels(pc.amplitude, pc.edge, sigma=_POOL_SIGMA * patch / n_grid)
    desc = _describe(channels, xy, patch=patch, n_grid=n_grid, n_rotations=n_rotations)
    pts = np.empty_like(xy)
    pts[:, 0] = (xy[:, 0] + 0.5) / sx - 0.5
    pts[:, 1] = (xy[:, 1] + 0.5) / sy - 0.5
    return pts, desc, size


def match_multimodal(desc_a: np.ndarray, desc_b: np.ndarray, *, ratio: float = 0.95, mutual: bool = True,
                     n_rotations: int = N_ROTATIONS, n_probe: int = 600) -> tuple[np.ndarray, np.ndarray]:
    """Match :func:`detect_multimodal` descriptors under the best global rotation hypothesis.

    Brute force on cosine similarity (the blocks have unit norm; distance sqrt(2 - 2 cos);
    :func:`~reglib.features.match_unit_descriptors`), deterministic. Each rotation hypothesis r
    is scored by the number of mutual nearest neighbours passing the ratio test between block 0
    of the first ``n_probe`` descriptors of a (the strongest, spread over the image) and block r
    of those of b; the winner (ties: the smaller rotation index) is matched in full.

    Parameters
    ----------
    desc_a, desc_b : (Ka, L), (Kb, L) float32 ndarray
        ``Features.descriptors`` of the two images; L a multiple of ``n_rotations``.
    ratio : float
        Lowe's ratio test on the distances, in (0, 1]; 1.0 keeps every nearest neighbour.
    mutual : bool
        Keep only pairs that are each other's nearest neighbour.
    n_rotations : int
        Blocks per descriptor: 12 for ``rotation_invariant=True`` (default), 1 for upright ones.
    n_probe : int
        Descriptors per image used to pick the rotation hypothesis.

    Returns
    -------
    idx_a, idx_b : (N,) intp ndarray
        Matched rows of ``desc_a`` and ``desc_b``, sorted by ``idx_a``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> d = rng.random((5, 24)).astype(np.float32)
    >>> d /= np.linalg.norm(d.reshape(5, 12, 2), axis=2, keepdims=True).repeat(2, axis=2).reshape(5, 24)
    >>> match_multimodal(d, d[::-1])
    (array([0, 1, 2, 3, 4]), array([4, 3, 2, 1, 0]))
    """
    a = np.asarray(desc_a, np.float32)
    b = np.asarray(desc_b, np.float32)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InputError(f"`desc_a` and `desc_b` must be (Ka, L) and (Kb, L), got {a.shape} and {b.shape}")
    if n_rotations < 1 or a.shape[1] % n_rotations:
        raise InputError(f"`n_rotations` must divide the descriptor length {a.shape[1]}, got {n_rotations}")
    if not 0.0 < ratio <= 1.0:
        raise InputError(f"`ratio` must be in (0, 1], got {ratio}")
    empty = (np.zeros(0, np.intp), np.zeros(0, np.intp))
    if len(a) == 0 or len(b) == 0:
        return empty
    block = a.shape[1] // n_rotations
    a0 = np.ascontiguousarray(a[:, :block])
    b_blocks = b.reshape(len(b), n_rotations, block)
    best_r = 0
    if n_rotations > 1:
        pa, pb = a0[:n_probe], b_blocks[:n_probe]
        counts = [len(_match_unit(pa, np.ascontiguousarray(pb[:, r]), ratio, True)[0]) for r in range(n_rotations)]
        best_r = int(np.argmax(counts))
    ia, ib = _match_unit(a0, np.ascontiguousarray(b_blocks[:, best_r]), ratio, mutual)
    return ia, ib

