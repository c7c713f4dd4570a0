"""The images' own similarity as evidence for a transform, where the support check finds no distinct peak.

Across stains and sensors fine structure differs, so the support check (:mod:`reglib.dense._confidence`)
often finds no distinct correlation peak for either of two estimates; the similarity of the images
at the right transform still stays higher than at a wrong one. :func:`local_similarity` measures it
at given points (zero-mean NCC of a patch of a with b resampled through the transform, no search),
:func:`evidence_z` is the sign test that one transform makes the images more similar than another at
clearly more places (on patches that do not overlap), and :func:`rate_over_no_motion` rates an
answer against no motion at all (:func:`evidence_over_no_motion`: its z alone). An answer that moves the images
must be rated over no motion by a margin (``NONE_MARGIN``, ``MIN_SHARE``) to count as usable: across stains a
wrong one can make the images no more similar than no motion at some places and no less at others, which the
sign test of ``EVIDENCE_Z`` alone lets through. Coordinates are (x, y) pixels, x the column.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .._transforms import KernelWarp
from ._fields import _as_fields, _downscaled
from ._flow import remap_planes, sample_positions
from ._options import DenseOptions

__all__ = ["EVIDENCE_Z", "MIN_NEIGHBOUR_SHARE", "MIN_REGION_SHARE", "MIN_SHARE", "MOVE_PX", "NEIGHBOUR_PX",
           "NONE_MARGIN", "OverNoMotion", "REGIONS", "REGION_PLACES", "evidence_over_no_motion", "evidence_z",
           "local_similarity", "rate_over_no_motion"]

EVIDENCE_PATCH = 12  # half-size of the patches of the similarity evidence (working px)
# a sign test's z at least (patches that do not overlap) for one estimate to be more similar than another at
# clearly more places (one-sided p about 3e-5): between what a right dense estimate reaches across stains and
# what a wrong one reaches across sensors
EVIDENCE_Z = 4.0
# an answer that moves a's evidence points by a median over MOVE_PX working px (where a 25 px patch's similarity
# can tell it from no motion) must be rated over no motion at a z of NONE_MARGIN at least, and be the more similar
# at MIN_SHARE of the places at least, to be usable: each between what answers worse than no motion reached and
# what usable ones did, on the shared multimodal pairs and the training halves of the stain-like families
# (benchmarks/README.md)
MOVE_PX = 2.0
NONE_MARGIN = 2.0
MIN_SHARE = 0.62
# ... and not be clearly short of MIN_NEIGHBOUR_SHARE in its comparisons with its neighbours (the answer moved by
# NEIGHBOUR_PX working px along a's axes): a right answer is where the similarity peaks, a wrong one about as
# similar as its neighbours. "Clearly": by more than two standard errors of a share over the places compared (a
# small or blurred image's few places cannot show a peak as clearly). Between the training answers that failed
# and those that succeeded, on the shared multimodal pairs and the training halves (benchmarks/README.md)
NEIGHBOUR_PX = 4
MIN_NEIGHBOUR_SHARE = 0.63
# the same comparisons region by region (a's working copy cut into REGIONS x REGIONS): an answer right over most
# of the image and wrong in one part (a missed local deformation) is a peak in most regions and about as similar
# as its neighbours in the wrong one. Regions with fewer than REGION_PLACES places are not judged. The weakest
# region counts when its share is under MIN_REGION_SHARE and clearly under the rest of the image's (a z of
# EVIDENCE_Z: an image whose right answer is a weak peak everywhere, a real scene with depth, is not one that misses
# a part). MIN_REGION_SHARE lies between the wrong regions of the answers that failed and the weakest regions of
# those that succeeded, on the wider generator's training pairs (same-modality images; benchmarks/README.md, issue 50)
REGIONS = 3
REGION_PLACES = 8
MIN_REGION_SHARE = 0.58


def local_similarity(field_a: np.ndarray, field_b: np.ndarray, transform: KernelWarp, points: np.ndarray,
                     half_patch: int, patches_a: _PatchesA | None = None) -> np.ndarray:
    """(G,) float64: at each point (x, y) of a, the zero-mean NCC of a's (2 h + 1)^2 patch with b's resampled
    through ``transform`` there (no search; over C channels, the mean of each channel's NCC); NaN where the patch
    leaves a or is mapped outside b, or either patch is flat.

    The evidence of a transform that needs no distinct peak: where fine structure differs between the images
    (across stains) the check finds none, yet the similarity at the right place stays higher than at a wrong
    one. Trusted input: (H, W, C) float32 fields, ``transform`` in their pixels; does not validate.
    ``patches_a``: a's patch statistics at ``points`` (:func:`_patches_a`) when the caller rates several
    transforms at the same points.
    """
    return _similarities(field_a, field_b, transform, points, half_patch, ((0, 0),), patches_a)[0]


@dataclass(frozen=True)
class _PatchesA:
    """a's side of :func:`_similarities` at its points, the same whatever the transform: the points' rows and
    columns, whether their patches lie inside a, and per channel the plane, its patch means and variances."""

    iy: np.ndarray
    ix: np.ndarray
    inside: np.ndarray
    planes: list[tuple[np.ndarray, np.ndarray, np.ndarray]]


def _patches_a(field_a: np.ndarray, points: np.ndarray, half_patch: int) -> _PatchesA:
    """:class:`_PatchesA` of ``field_a`` at ``points`` for patches of half-size ``half_patch``."""
    h, w = field_a.shape[:2]
    k = (2 * half_patch + 1, 2 * half_patch + 1)
    ix, iy = np.rint(points[:, 0]).astype(np.intp), np.rint(points[:, 1]).astype(np.intp)
    inside = (ix >= half_patch) & (ix < w - half_patch) & (iy >= half_patch) & (iy < h - half_patch)
    ix, iy = np.clip(ix, 0, w - 1), np.clip(iy, 0, h - 1)
    planes = []
    for c in range(field_a.shape[2]):
        x = np.ascontiguousarray(field_a[:, :, c])
        mx = cv2.boxFilter(x, cv2.CV_32F, k)[iy, ix]
        planes.append((x, mx, cv2.boxFilter(x * x, cv2.CV_32F, k)[iy, ix] - mx * mx))
    return _PatchesA(iy=iy, ix=ix, inside=inside, planes=planes)


def _similarities(field_a: np.ndarray, field_b: np.ndarray, transform: KernelWarp, points: np.ndarray,
                  half_patch: int, shifts: tuple[tuple[int, int], ...],
                  patches_a: _PatchesA | None = None) -> np.ndarray:
    """(S, G) float64: :func:`local_similarity` of ``transform`` moved by each shift (dx, dy) of a's pixels, i.e.
    of p -> transform(p + shift): a's patch at p against b resampled through ``transform`` at p + shift. b is
    resampled once for all the shifts; (0, 0) gives :func:`local_similarity` itself. ``patches_a``: as
    :func:`local_similarity`'s."""
    h, w = field_a.shape[:2]
    out = np.full((len(shifts), len(points)), np.nan)
    if not len(points):
        return out
    warped, valid = remap_planes(field_b, sample_positions(transform, (h, w)))
    k = (2 * half_patch + 1, 2 * half_patch + 1)
    pa = _patches_a(field_a, points, half_patch) if patches_a is None else patches_a
    iy, ix, inside = pa.iy, pa.ix, pa.inside
    cover = cv2.boxFilter(valid.astype(np.float32), cv2.CV_32F, k, normalize=True)
    # the shifted patch must lie inside a's frame as well: its position in the shifted rows and columns
    at = [(np.clip(iy + dy, 0, h - 1), np.clip(ix + dx, 0, w - 1),
           inside & (ix + dx >= half_patch) & (ix + dx < w - half_patch) & (iy + dy >= half_patch)
           & (iy + dy < h - half_patch)) for dx, dy in shifts]
    total, n = np.zeros(out.shape), np.zeros(out.shape)
    for c, (x, mx, vx) in enumerate(pa.planes):
        y = warped[c]
        box_y, box_yy = cv2.boxFilter(y, cv2.CV_32F, k), cv2.boxFilter(y * y, cv2.CV_32F, k)
        for s, (dx, dy) in enumerate(shifts):
            ry, rx, _ = at[s]
            my = box_y[ry, rx]
            vy = box_yy[ry, rx] - my * my
            cxy = cv2.boxFilter(x * _moved(y, dx, dy), cv2.CV_32F, k)[iy, ix] - mx * my
            ok = (vx > 1e-8) & (vy > 1e-8)
            total[s, ok] += cxy[ok] / np.sqrt(vx[ok] * vy[ok])
            n[s, ok] += 1
    for s in range(len(shifts)):
        ry, rx, ins = at[s]
        good = ins & (cover[ry, rx] > 0.999) & (n[s] > 0)
        out[s, good] = total[s, good] / n[s, good]
    return out


def _moved(plane: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """``plane`` read at (x + dx, y + dy) at each pixel (x, y), zero where that leaves it (only patches inside
    it are read)."""
    if not dx and not dy:
        return plane
    h, w = plane.shape
    out = np.zeros_like(plane)
    out[max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)] = \
        plane[max(0, dy):h - max(0, -dy), max(0, dx):w - max(0, -dx)]
    return out


def _evidence_points(shape: tuple[int, ...], step: int) -> np.ndarray:
    """(G, 2) points (x, y) of a grid whose patches do not overlap: spacing the larger of ``step`` and the patch,
    offset by half of it."""
    h, w = shape[:2]
    spacing = max(int(step), 2 * EVIDENCE_PATCH + 1)
    ys, xs = np.mgrid[spacing // 2:h:spacing, spacing // 2:w:spacing]
    return np.c_[xs.ravel(), ys.ravel()].astype(np.float64)


def evidence_z(field_a: np.ndarray, field_b: np.ndarray, better: KernelWarp, worse: KernelWarp, step: int) -> float:
    """The sign test's z that ``better`` makes the fields more similar than ``worse`` does (both in their pixels).

    On a grid of a whose patches do not overlap (spacing the larger of ``step`` and the patch, 2 * 12 + 1 px,
    offset by half of it, so that the points are about independent samples), the local similarity
    (:func:`local_similarity`) at both transforms; z = (wins - n / 2) / sqrt(n / 4)
    over the n points where both are measured and differ (0.0 for none). Positive: ``better`` is more similar
    at more points. Trusted input: (H, W, C) float32 fields with the same C; does not validate.
    """
    wins, n = _sign_test(field_a, field_b, better, worse, step)
    return _z(wins, n)


def _sign_test(field_a: np.ndarray, field_b: np.ndarray, better: KernelWarp, worse: KernelWarp,
               step: int) -> tuple[int, int]:
    """(wins, n) of :func:`evidence_z`: the points where ``better`` is more similar, of the n measured for both
    that differ."""
    points = _evidence_points(field_a.shape, step)
    patches = _patches_a(field_a, points, EVIDENCE_PATCH)  # a's side once for both transforms
    s1 = local_similarity(field_a, field_b, better, points, EVIDENCE_PATCH, patches)
    s2 = local_similarity(field_a, field_b, worse, points, EVIDENCE_PATCH, patches)
    return _wins(s1, s2)


def _wins(s1: np.ndarray, s2: np.ndarray) -> tuple[int, int]:
    """(wins, n): where ``s1`` is the more similar, of the n places measured in both that differ."""
    both = np.isfinite(s1) & np.isfinite(s2) & (s1 != s2)
    return int(np.count_nonzero(s1[both] > s2[both])), int(np.count_nonzero(both))


def _neighbour_shifts(px: int) -> tuple[tuple[int, int], ...]:
    """The answer itself, (0, 0), and its four neighbours ``px`` away along a's axes."""
    return (0, 0), (px, 0), (-px, 0), (0, px), (0, -px)


def _z(wins: int, n: int) -> float:
    """The sign test's z of ``wins`` out of ``n`` (0.0 for none)."""
    return float((wins - n / 2.0) / math.sqrt(n / 4.0)) if n else 0.0


@dataclass(frozen=True)
class OverNoMotion:
    """How the images rate an answer over no motion (:func:`rate_over_no_motion`).

    Attributes
    ----------
    z : float
        The sign test's z of the answer over the identity (:func:`evidence_z`); positive: the answer makes the
        images more similar at more places.
    share : float
        The share of those places where the answer is the more similar (0.5 where none was measured): unlike
        ``z`` it does not grow with the image's size, so an answer right on a part of a large image alone
        stays short of :data:`MIN_SHARE`.
    moved : float
        The median distance, working px, between where the answer and no motion take a's evidence points: at
        most :data:`MOVE_PX`, the two are too close for the patches to tell apart.

    neighbours : float
        The share of the comparisons (each place, each of the four neighbours of the answer: it moved by
        :data:`NEIGHBOUR_PX` along a's axes) where the answer is the more similar (0.5 where none was measured):
        a right answer is a peak of the similarity, a wrong one about as similar as its neighbours.
    places : float
        The places of those comparisons (the comparisons over the four neighbours, a quarter of them; 0 for
        none): the share's standard error is at most 1 / (2 sqrt(places)).
    weakest : float
        The lowest ``neighbours`` share of a region of a (:data:`REGIONS` x :data:`REGIONS`) with at least
        :data:`REGION_PLACES` places (1.0 where none has): where the answer is least a peak.
    weakest_z : float
        How clearly that region's share is below the other judged regions' together (the z of the difference of
        two shares; 0.0 where fewer than two regions are judged).
    """

    z: float
    share: float
    moved: float
    neighbours: float = 1.0
    places: float = 0.0
    weakest: float = 1.0
    weakest_z: float = 0.0

    @property
    def short_of_margin(self) -> bool:
        """The answer moves the images (``moved`` over :data:`MOVE_PX`) yet is not rated over no motion by
        :data:`NONE_MARGIN`, or is the more similar at under :data:`MIN_SHARE` of the places, or than its
        neighbours clearly less often than :data:`MIN_NEIGHBOUR_SHARE` (:attr:`below_neighbours`): the images do
        not back it clearly enough for a usable answer."""
        return self.moved > MOVE_PX and (self.z < NONE_MARGIN or self.share < MIN_SHARE or self.below_neighbours)

    @property
    def below_neighbours(self) -> bool:
        """``neighbours`` is clearly short of :data:`MIN_NEIGHBOUR_SHARE`: by more than two standard errors of a
        share over ``places`` (1 / sqrt(places)); never with no place compared."""
        return self.places > 0 and self.neighbours + 1.0 / math.sqrt(self.places) < MIN_NEIGHBOUR_SHARE

    @property
    def weak_region(self) -> bool:
        """A region of a where the answer is the more similar than its neighbours under :data:`MIN_REGION_SHARE`
        of the comparisons (``weakest``), clearly less often than in the rest of a (``weakest_z`` at least
        :data:`EVIDENCE_Z`): the answer misses a part of the image."""
        return self.weakest < MIN_REGION_SHARE and self.weakest_z >= EVIDENCE_Z


def rate_over_no_motion(image_a: np.ndarray, image_b: np.ndarray, transform: KernelWarp,
                        options: DenseOptions) -> OverNoMotion:
    """How clearly the images rate ``transform`` (a -> b, original pixels) over no motion, and how far apart the two
    take a's evidence points, on the working copies of ``options.max_side`` (:class:`OverNoMotion`).

    ``image_a``, ``image_b``: what the dense stage correlates ((H, W) grey or (H, W, C) fields, the same C);
    trusted input otherwise.
    """
    ga, gb, answer, none = _working_copies(image_a, image_b, transform, options)
    points = _evidence_points(ga.shape, options.step)
    moved = float(np.median(np.linalg.norm(answer(points) - none(points), axis=1))) if len(points) else 0.0
    patches = _patches_a(ga, points, EVIDENCE_PATCH)  # a's side once for the answer and no motion
    near = _similarities(ga, gb, answer, points, EVIDENCE_PATCH, _neighbour_shifts(NEIGHBOUR_PX), patches)
    wins, n = _wins(near[0], local_similarity(ga, gb, none, points, EVIDENCE_PATCH, patches))
    # each place's wins over the answer's neighbours, and its comparisons: summed over a, and region by region
    measured = np.isfinite(near[0]) & np.isfinite(near[1:]) & (near[0] != near[1:])
    won_at, compared_at = (measured & (near[0] > near[1:])).sum(0), measured.sum(0)
    won, compared = int(won_at.sum()), int(compared_at.sum())
    return OverNoMotion(z=_z(wins, n), share=wins / n if n else 0.5, moved=moved,
                        neighbours=won / compared if compared else 0.5, places=compared / (len(near) - 1),
                        **_weakest_region(won_at, compared_at, len(near) - 1, points, ga.shape))


def _weakest_region(won_at: np.ndarray, compared_at: np.ndarray, neighbours: int, points: np.ndarray,
                    shape: tuple[int, ...]) -> dict[str, float]:
    """:attr:`OverNoMotion.weakest` and ``weakest_z``: ``won_at`` and ``compared_at`` each place's wins over its
    ``neighbours`` comparisons and the comparisons measured, at ``points`` (x, y) of a field of ``shape``."""
    h, w = shape[:2]
    row = np.minimum((points[:, 1] * REGIONS / h).astype(int), REGIONS - 1)
    col = np.minimum((points[:, 0] * REGIONS / w).astype(int), REGIONS - 1)
    region = row * REGIONS + col
    won = np.bincount(region, weights=won_at, minlength=REGIONS * REGIONS)
    compared = np.bincount(region, weights=compared_at, minlength=REGIONS * REGIONS)
    judged = compared >= REGION_PLACES * neighbours
    if not judged.any():
        return {"weakest": 1.0, "weakest_z": 0.0}
    won, compared = won[judged], compared[judged]
    weak = int(np.argmin(won / compared))
    share = float(won[weak] / compared[weak])
    rest_won, rest = float(won.sum() - won[weak]), float(compared.sum() - compared[weak])
    if not rest:
        return {"weakest": share, "weakest_z": 0.0}
    pooled = (won[weak] + rest_won) / (compared[weak] + rest)
    spread = math.sqrt(max(pooled * (1.0 - pooled), 1e-12) * (1.0 / compared[weak] + 1.0 / rest))
    return {"weakest": share, "weakest_z": float((rest_won / rest - share) / spread)}


def evidence_over_no_motion(image_a: np.ndarray, image_b: np.ndarray, transform: KernelWarp,
                            options: DenseOptions) -> float:
    """How clearly the images themselves rate ``transform`` (a -> b, original pixels) over no motion at all.

    :func:`evidence_z` of ``transform`` over the identity on the working copies of ``options.max_side``:
    at most -4 (``-EVIDENCE_Z``), the identity makes the images more similar at clearly more places
    (the answer is worse than no motion); at least 4, ``transform`` clearly better. ``image_a``,
    ``image_b``: what the dense stage correlates ((H, W) grey or (H, W, C) fields, the same C); trusted input
    otherwise.
    """
    # the z alone: rate_over_no_motion's neighbour comparisons are not needed for it
    return evidence_z(*_working_copies(image_a, image_b, transform, options), options.step)


def _working_copies(image_a: np.ndarray, image_b: np.ndarray, transform: KernelWarp,
                    options: DenseOptions) -> tuple[np.ndarray, np.ndarray, KernelWarp, KernelWarp]:
    """The fields at the working size of ``options.max_side``, and ``transform`` and no motion in their pixels."""
    fa, fb = _as_fields(image_a, image_b)
    sa = min(1.0, options.max_side / max(fa.shape[:2]))
    sb = min(1.0, options.max_side / max(fb.shape[:2]))
    ga, _ = _downscaled(fa, None, sa)
    gb, _ = _downscaled(fb, None, sb)
    return ga, gb, transform.rescaled(sa, sb), KernelWarp.identity(2).rescaled(sa, sb)
