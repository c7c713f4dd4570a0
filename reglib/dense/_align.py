"""Intensity-based rigid alignment of two images by normalized mutual information (NMI).

For pairs where features find too little (blurred functional images such as PET or SPECT
against MR or CT, whose shared structure is the outline of the organ and a few coarse blobs):
the rigid map of highest normalized mutual information [1]_ between intensity classes of the two
images (colour classes for pseudo-colour images), found by a grid search and Powell's method,
coarse to fine (:func:`align_rigid`).

Coordinates: (x, y) pixels, x the column, the centre of the top-left pixel (0, 0); the map takes
pixels of image a to pixels of image b.

References
----------
.. [1] C. Studholme, D. L. G. Hill, D. J. Hawkes, "An overlap invariant entropy measure of 3D
       medical image alignment", Pattern Recognition 32(1), 1999.
       :doi:`10.1016/S0031-3203(98)00091-0`
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from ..features import normalize_intensity

__all__ = ["RigidAlignment", "align_rigid"]


@dataclass(frozen=True, eq=False)
class RigidAlignment:
    """The rigid map of highest NMI found by :func:`align_rigid`, and how well it stands out.

    Attributes
    ----------
    matrix : (2, 3) float64 ndarray
        x_b = matrix[:, :2] @ x_a + matrix[:, 2] in pixels of the images given.
    nmi : float
        Its NMI (H(A) + H(B)) / H(A, B), in [1, 2] (0 when the overlap is under a fifth of a), on
        the finest working copies.
    nmi_compare : float
        The NMI there of the ``compare`` transform given to :func:`align_rigid` (0 without it).
    peak : float
        How far the grid search's best NMI stands out: (best - median) / (1.4826 MAD) over the grid.
    """

    matrix: np.ndarray
    nmi: float
    nmi_compare: float
    peak: float


_MI_COARSE_SIDE = 64  # longer side of the coarsest working copy of align_rigid (its grid search)
_MI_SIDES = (64, 128, 256)  # working sizes of the coarse-to-fine NMI maximization


def _class_source(image: np.ndarray, max_side: int) -> tuple[np.ndarray, bool, float, float]:
    """Stretched intensities for :func:`_labels`: (h, w, C) float32 in [0, 1] at a longer side of at
    most ``max_side``, whether the image is colour (C = 3) or grey (C = 1), and the scales w / W, h / H.

    Colour counts where the chroma is not negligible (pseudo-colour PET / SPECT, photographs):
    mutual information needs only a class per pixel, and luminance would merge the colours of a
    pseudo-colour scale that stand for different values.
    """
    arr = np.nan_to_num(np.asarray(image).astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    if arr.ndim == 3:
        arr = arr[:, :, :3]
    h, w = arr.shape[:2]
    s = min(1.0, max_side / max(h, w))
    size = (max(1, round(w * s)), max(1, round(h * s)))
    small = cv2.resize(arr, size, interpolation=cv2.INTER_AREA) if size != (w, h) else arr
    colour = False
    if small.ndim == 3:
        chroma = small.max(axis=2) - small.min(axis=2)
        colour = bool(np.mean(chroma > 0.1 * max(float(np.abs(small).max()), 1e-6)) > 0.05)
    if colour:
        out = np.stack([normalize_intensity(small[:, :, k]) for k in range(3)], axis=2)
    else:
        out = normalize_intensity(small)[:, :, None]
    return out, colour, size[0] / w, size[1] / h


def _labels(source: tuple[np.ndarray, bool, float, float], side: int) -> tuple[np.ndarray, int, float, float]:
    """Per-pixel intensity class of a working copy (longer side ``side``) for a joint histogram, and
    the working copy's scales to the image: 24 grey levels, or 4 levels per colour channel (64)."""
    chans, colour, sx0, sy0 = source
    h, w = chans.shape[:2]
    s = side / max(h, w)
    size = (max(1, round(w * s)), max(1, round(h * s)))
    work = cv2.resize(chans, size, interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    work = work.reshape(size[1], size[0], -1)
    if colour:
        q = np.minimum((work * 4).astype(np.int32), 3)
        lab, n_labels = (q[:, :, 0] * 4 + q[:, :, 1]) * 4 + q[:, :, 2], 64
    else:
        lab, n_labels = np.minimum((work[:, :, 0] * 24).astype(np.int32), 23), 24
    return lab.astype(np.float32), n_labels, size[0] / w * sx0, size[1] / h * sy0


def _nmi(la: np.ndarray, na: int, wb: np.ndarray, nb: int) -> float:
    """Normalized mutual information (H(A) + H(B)) / H(A, B) over the pixels where ``wb`` >= 0."""
    valid = wb >= 0
    if valid.sum() < 0.2 * valid.size:
        return 0.0
    joint = np.bincount(la[valid].astype(np.intp) * nb + wb[valid].astype(np.intp), minlength=na * nb)
    p = joint.reshape(na, nb) / float(valid.sum())

    def entropy(q: np.ndarray) -> float:
        q = q[q > 0]
        return float(-(q * np.log(q)).sum())

    h_joint = entropy(p)
    return (entropy(p.sum(axis=1)) + entropy(p.sum(axis=0))) / h_joint if h_joint > 0 else 0.0


def _pixel_map(sx: float, sy: float) -> np.ndarray:
    """3 x 3 map of image pixels to the pixels of a copy resized by (sx, sy) (pixel centres kept)."""
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


def _rigid(params: np.ndarray, centre: np.ndarray, unit: float) -> np.ndarray:
    """3 x 3 rigid map of pixels: rotation by params[0] about ``centre``, shift params[1:3] * ``unit``."""
    c, s = np.cos(params[0]), np.sin(params[0])
    rot = np.array([[c, -s], [s, c]])
    out = np.eye(3)
    out[:2, :2] = rot
    out[:2, 2] = np.asarray(params[1:3]) * unit + centre - rot @ centre
    return out


def _nmi_cost(labels_a: tuple[np.ndarray, int], labels_b: tuple[np.ndarray, int], from_work_a: np.ndarray,
              to_work_b: np.ndarray, centre: np.ndarray, unit: float) -> Callable[[np.ndarray], float]:
    """The cost -NMI of rigid parameters (angle, shift) on one level's working copies (class maps).

    b's classes are resampled (nearest) onto a's working grid; pixels mapped outside b count as
    outside the overlap.
    """
    la, na = labels_a
    lb, nb = labels_b
    h, w = la.shape

    def cost(p: np.ndarray) -> float:
        m = (to_work_b @ _rigid(p, centre, unit) @ from_work_a)[:2]
        wb = cv2.warpAffine(lb, m, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
        return -_nmi(la, na, wb, nb)

    return cost


def align_rigid(image_a: np.ndarray, image_b: np.ndarray, *, max_angle: float = 15.0, max_shift: float = 0.2,
                compare: Callable[[np.ndarray], np.ndarray] | None = None) -> RigidAlignment:
    """Rigid map a -> b maximizing normalized mutual information ([1]_), coarse to fine.

    For pairs where features find too little (blurred functional images such as PET or SPECT
    against MR or CT, whose shared structure is the outline of the organ and a few coarse blobs):
    intensity classes of both images (grey levels, or colour classes), a grid search over rotations within
    ``max_angle`` degrees (5 degree steps) and shifts within ``max_shift`` of a's longer side on
    64 px working copies, then Powell's method on the rotation and the shift at 128 and 256 px.
    Rigid in pixels: the two images are taken to have the same pixel size.

    Parameters
    ----------
    image_a, image_b : ndarray
        (H, W) or (H, W, 3), any real dtype; b is resampled (nearest class) onto a's grid.
    max_angle, max_shift : float
        Extent of the grid search (degrees; share of a's longer side).
    compare : callable, optional
        A transform ((K, 2) points of a -> (K, 2) points of b, in pixels) whose NMI is measured on
        the same grid, to weigh another estimate against the rigid map.

    Returns
    -------
    RigidAlignment
        The map (``matrix``), its NMI, that of ``compare`` and the grid search's ``peak``.

    Examples
    --------
    >>> from skimage.data import camera
    >>> img = camera()[::2, ::2]
    >>> shifted = np.roll(img, (6, -4), axis=(0, 1))       # b(x, y) = a(x + 4, y - 6)
    >>> np.round(align_rigid(img, shifted).matrix[:, 2])
    array([-4.,  6.])
    """
    from scipy import optimize

    ha, wa = np.asarray(image_a).shape[:2]
    centre = np.array([(wa - 1) / 2.0, (ha - 1) / 2.0])
    unit = max(ha, wa) / _MI_COARSE_SIDE  # shifts in pixels of a's coarsest working copy
    params = np.zeros(3)
    peak, best = 0.0, 0.0
    source_a, source_b = _class_source(image_a, _MI_SIDES[-1]), _class_source(image_b, _MI_SIDES[-1])
    for level, side in enumerate(_MI_SIDES):
        la, na, sxa, sya = _labels(source_a, side)
        lb, nb, sxb, syb = _labels(source_b, side)
        h, w = la.shape
        cost = _nmi_cost((la, na), (lb, nb), np.linalg.inv(_pixel_map(sxa, sya)), _pixel_map(sxb, syb), centre, unit)
        if level == 0:
            reach = max_shift * _MI_COARSE_SIDE
            shifts = np.arange(-np.floor(reach / 2) * 2, reach + 1e-9, 2.0)
            angles = np.radians(np.arange(-max_angle, max_angle + 1e-9, 5.0))
            grid = np.array([[t, x, y] for t in angles for x in shifts for y in shifts])
            values = np.array([cost(p) for p in grid])
            params = grid[int(np.argmin(values))]
            med = np.median(values)
            peak = float((med - values.min()) / (1.4826 * np.median(np.abs(values - med)) + 1e-9))
        step = 0.5 ** level  # initial Powell steps: 2 degrees and a coarse pixel, halved per level
        res = optimize.minimize(cost, params, method="Powell",
                                options={"xtol": 1e-2, "ftol": 1e-5, "maxfev": 300,
                                         "direc": np.diag([np.radians(2.0) * step, step, step])})
        params, best = res.x, -float(res.fun)
    matrix = _rigid(params, centre, unit)[:2]
    nmi_cmp = 0.0
    if compare is not None:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        pa = np.stack([(xx.ravel() + 0.5) / sxa - 0.5, (yy.ravel() + 0.5) / sya - 0.5], axis=1)
        pb = np.asarray(compare(pa), np.float64)
        mx = ((pb[:, 0] + 0.5) * sxb - 0.5).reshape(h, w).astype(np.float32)
        my = ((pb[:, 1] + 0.5) * syb - 0.5).reshape(h, w).astype(np.float32)
        wb = cv2.remap(lb, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
        nmi_cmp = _nmi(la, na, wb, nb)
    return RigidAlignment(matrix=matrix, nmi=best, nmi_compare=nmi_cmp, peak=peak)
