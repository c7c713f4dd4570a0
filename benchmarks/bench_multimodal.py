"""Multimodal image matching benchmark: reglib's phase-congruency / MIM features against SIFT.

Data: ``<data>/multimodal/<field>/<kind>/<pair>/{a.png, b.png, landmarks.txt}`` (82 pairs of 17
kinds from the data base of Jiang, Ma et al., "A review of multimodal image matching", Information
Fusion 73, 2021; see ``<data>/README.md``). Error of a pair: mean distance between f(landmark in a)
and the landmark in b; success: error under 5 px. Every method is scored on the transform it
returns, also when it reports a ``reason`` (the identity for "too few matches"); only a failed
OpenCV homography scores inf.

Methods (``--methods``); the six multimodal variants share one detection and matching per pair:

- ``multimodal``         :func:`reglib.features.detect_multimodal` on both images ->
                         :func:`~reglib.features.match_multimodal` ->
                         ``reglib.filter_matches(src, dst, rng=0)`` with its defaults -> transform.
- ``mm_affine``          the same putatives, ``filter_matches`` with ``AFFINE`` (pure affine L2E,
                         one layer, annealing to sigma^2 = 0.05 * 0.5^9).
- ``mm_refined``         putatives refined by :func:`~reglib.features.refine_matches`
                         (structure-field correlation), then ``AFFINE``.
- ``mm_refined_h``       refined, then the same with ``linear="homography"``.
- ``mm_refined_2stage``  refined, ``AFFINE``, then the default kernel L2E (``KERNEL``) on the
                         matches within ``GATE_PX`` of the affine fit (non-rigid pairs).
- ``mm_fit``             the pipeline's estimate on the refined putatives
                         (:func:`reglib.matching._multimodal.multimodal_fit`):
                         ``mm_refined_2stage``, and where that has fewer than
                         ``MULTIMODAL_MIN_INLIERS`` inliers the rigid map of highest
                         normalized mutual information (:func:`~reglib.dense._align.align_rigid`)
                         unless the fit's is clearly higher. What ``features="multimodal"`` gives
                         with ``dense=False``, without the pipeline's reading and confidence map.
- ``pipeline_mm``        ``match_images(a, b, features="multimodal", options={"dense": False}, rng=0)``
                         (listed by default once the pipeline knows the name).
- ``pipeline_mm_dense``  ``match_images(a, b, features="multimodal", rng=0)`` with its defaults: the dense
                         stage on structure fields (``--methods pipeline_mm_dense`` to run it).
- ``auto``               a sketch of ``features="auto"``: ``sift`` first; when it reports a ``reason``
                         or fewer than ``AUTO_MIN_INLIERS`` inliers, ``mm_fit`` (the
                         seconds are both when it falls back; the SIFT run is shared with ``sift``).
- ``sift``               ``match_images(a, b, rng=0)`` with its defaults (SIFT, L2E, dense stage).
- ``shape_context``      ``match_images(a, b, features="shape_context", rng=0)``.
- ``sift_magsac``        OpenCV SIFT + brute-force ratio test 0.8 + ``cv2.findHomography(USAC_MAGSAC, 3 px)``.

Landmark self-consistency (printed after the table): each landmark predicted from the pair's
other landmarks (least-squares homography, interpolating thin-plate spline), mean leave-one-out
error per pair; the pairs over 5 px by both are listed with every method's error on them.

Seconds are wall and CPU (``time.process_time``) time per pair: detection of both images and
matching, plus refinement and the estimator for the variants that use them. The machine is
shared, so wall time depends on its load; CPU time does much less.

Usage (from the project root)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_multimodal.py            # all, 10-30 min
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_multimodal.py --quick    # 1 pair a kind
    ... --kinds MR_PET,SPECT_CT --methods mm_fit,mm_refined_2stage
    ... --detect '{"max_side": 640}' --match '{"ratio": 0.9}' --figures

Not run by CI.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
from _stats import roc_auc

from reglib import filter_matches, match_images
from reglib.features import (
    detect_multimodal,
    detect_sift,
    match_descriptors,
    match_multimodal,
    refine_matches,
    to_gray_uint8,
)
from reglib.matching import FEATURES
from reglib.matching._multimodal import multimodal_fit

SUCCESS_PX = 5.0
# pure affine L2E with a longer annealing (sigma^2 down to 0.05 * 0.5^9): the estimator setting
# these putatives want (see the module notes and the report table)
AFFINE = {"n_centers": 0, "max_centers": 0, "max_layers": 1, "n_anneal": 9}
KERNEL = {"n_anneal": 9, "max_layers": 1}
GATE_PX = 10.0  # two-stage: matches farther than this from the affine fit do not enter the kernel fit
MM_METHODS = ("multimodal", "mm_affine", "mm_refined", "mm_refined_h", "mm_refined_2stage", "mm_fit")
AUTO_MIN_INLIERS = 30  # "auto" sketch: fall back to the multimodal path below this many SIFT inliers
ALL_METHODS = MM_METHODS + ("pipeline_mm", "pipeline_mm_dense", "auto", "sift", "shape_context", "sift_magsac")
DEFAULT_METHODS = MM_METHODS + ("auto", "sift", "shape_context", "sift_magsac")


def clock() -> np.ndarray:
    """(wall, CPU) seconds now: the machine is shared, so CPU time per pair is reported beside wall time."""
    return np.array([time.perf_counter(), time.process_time()])


def load_pairs(root: Path, kinds: set[str] | None, quick: bool) -> list[tuple[str, str, Path]]:
    pairs = []
    for field in sorted(p for p in (root / "multimodal").iterdir() if p.is_dir()):
        for kind in sorted(p for p in field.iterdir() if p.is_dir()):
            name = f"{field.name[:6]}/{kind.name}"
            if kinds and kind.name not in kinds and name not in kinds:
                continue
            items = sorted(p for p in kind.iterdir() if (p / "landmarks.txt").exists())
            pairs += [(name, p.name, p) for p in (items[:1] if quick else items)]
    return pairs


def read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)
    return img


def pair_error(transform, land: np.ndarray) -> float:
    if transform is None:
        return float("inf")
    pred = np.asarray(transform(land[:, :2]), float)
    if not np.all(np.isfinite(pred)):
        return float("inf")
    return float(np.linalg.norm(pred - land[:, 2:], axis=1).mean())


def landmark_consistency(land: np.ndarray) -> tuple[float, float]:
    """How well a pair's landmarks predict each other: mean leave-one-out error, px, of (homography, thin-plate spline).

    Each landmark of b is predicted from the other landmarks by a least-squares homography and
    by an interpolating thin-plate spline fitted to them, and compared with where it was placed.
    When both means are over SUCCESS_PX, no smooth map the other landmarks describe puts this one
    within the success radius: the pair's error measures the placement (or a deformation finer than
    the landmarks' spacing) as much as the method.
    """
    from scipy.interpolate import RBFInterpolator

    pa, pb = land[:, :2], land[:, 2:]
    n = len(land)
    if n < 5:
        return float("nan"), float("nan")
    err_h, err_t = [], []
    for i in range(n):
        rest = np.arange(n) != i
        hmat, _ = cv2.findHomography(pa[rest], pb[rest], 0)
        if hmat is not None:
            q = cv2.perspectiveTransform(pa[i:i + 1].reshape(1, 1, 2), hmat).reshape(2)
            err_h.append(float(np.linalg.norm(q - pb[i])))
        tps = RBFInterpolator(pa[rest], pb[rest], kernel="thin_plate_spline")
        err_t.append(float(np.linalg.norm(tps(pa[i:i + 1])[0] - pb[i])))
    return (float(np.mean(err_h)) if err_h else float("nan")), float(np.mean(err_t))


class MultimodalPair:
    """Features, putatives and refined putatives of one pair, computed once for all variants."""

    def __init__(self, a, b, det, mat):
        t0 = clock()
        fa, fb = detect_multimodal(a, **det), detect_multimodal(b, **det)
        ia, ib = match_multimodal(fa.descriptors, fb.descriptors, **mat)
        self.src, self.dst = fa.points[ia], fb.points[ib]
        self.has_keypoints = bool(len(fa.points) and len(fb.points))
        self.t_features = clock() - t0
        self.a, self.b = a, b
        self._refined = None

    def refined(self):
        if self._refined is None:
            t0 = clock()
            dst, _ = refine_matches(self.a, self.b, self.src, self.dst)
            self._refined = (dst, clock() - t0)
        return self._refined


def run_multimodal(pair: MultimodalPair, method: str, filt: dict):
    """(transform or None, drawable match, seconds) of one multimodal variant."""
    src, dst, extra = pair.src, pair.dst, 0.0
    if method.startswith("mm_refined") or method == "mm_fit":
        dst, extra = pair.refined()
    t0 = clock()
    if method == "multimodal":
        res = filter_matches(src, dst, options=filt or None, rng=0)
    elif method == "mm_refined_h":
        res = filter_matches(src, dst, options={**AFFINE, "linear": "homography", **filt}, rng=0)
    elif method == "mm_refined_2stage":
        first = filter_matches(src, dst, options={**AFFINE, **filt}, rng=0)
        res = first
        if first.reason is None:
            keep = np.linalg.norm(first.transform(src) - dst, axis=1) < GATE_PX
            second = filter_matches(src[keep], dst[keep], options={**KERNEL, **filt}, rng=0)
            if second.reason is None:
                inl = np.zeros(len(src), bool)
                inl[np.flatnonzero(keep)[second.inliers]] = True
                res = SimpleNamespace(reason=None, transform=second.transform, inliers=inl)
    elif method == "mm_fit":
        res = multimodal_fit(pair.a, pair.b, src, dst, np.random.default_rng(0), has_keypoints=pair.has_keypoints)
    else:  # mm_affine, mm_refined
        res = filter_matches(src, dst, options={**AFFINE, **filt}, rng=0)
    sec = pair.t_features + extra + clock() - t0
    match = SimpleNamespace(src=src, dst=dst, inliers=res.inliers)
    return res.transform, match, sec


def run_sift_magsac(a, b):
    ga, gb = to_gray_uint8(a), to_gray_uint8(b)
    fa, fb = detect_sift(ga), detect_sift(gb)
    ia, ib = match_descriptors(fa.descriptors, fb.descriptors, ratio=0.8)
    if len(ia) < 4:
        return None, None
    hmat, inl = cv2.findHomography(fa.points[ia], fb.points[ib], cv2.USAC_MAGSAC, 3.0)
    if hmat is None:
        return None, None

    def f(p):
        return cv2.perspectiveTransform(np.asarray(p, np.float64).reshape(-1, 1, 2), hmat).reshape(-1, 2)
    return f, SimpleNamespace(src=fa.points[ia], dst=fb.points[ib], inliers=inl.ravel().astype(bool))


def run(method, a, b, args):
    """(transform or None, drawable match) of a non-multimodal method."""
    if method == "sift_magsac":
        return run_sift_magsac(a, b)
    kw = {"sift": {}, "shape_context": {"features": "shape_context"},
          "pipeline_mm": {"features": "multimodal", "options": {"dense": False}},
          "pipeline_mm_dense": {"features": "multimodal"}}[method]
    m = match_images(a, b, rng=0, **kw)
    return m.transform, m  # with a ``reason`` too: the identity (or a weak fit) is what the caller gets


def table(rows: dict, methods: list[str], kinds: list[str]) -> str:
    head = "| kind | n | " + " | ".join(f"{m} ok % / med px / s / cpu s" for m in methods) + " |"
    lines = [head, "|" + " --- |" * (2 + len(methods))]
    for kind in kinds + ["overall"]:
        cells = []
        n = 0
        for m in methods:
            res = [r for r in rows[m] if kind == "overall" or r[0] == kind]
            n = len(res)
            err = np.array([r[2] for r in res])
            sec = np.array([r[3] for r in res]).reshape(-1, 2)
            ok = 100.0 * np.mean(err < SUCCESS_PX) if n else float("nan")
            med = np.median(err) if n else float("nan")
            cells.append(f"{ok:.0f} / {med:.2f} / {np.median(sec[:, 0]):.2f} / {np.median(sec[:, 1]):.2f}")
        lines.append(f"| {kind} | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def consistency_report(rows: dict, methods: list[str], consistency: dict) -> str:
    """The pairs whose own landmarks disagree (:func:`landmark_consistency` over SUCCESS_PX by both models),
    each method's error on them, and every method's success rate on the other pairs."""
    def loose(key) -> bool:
        return bool(min(consistency[key]) > SUCCESS_PX)

    bad = [key for key in consistency if loose(key)]
    lines = [f"\nLandmark self-consistency: a landmark predicted from the pair's other landmarks (least-squares "
             f"homography / thin-plate spline), mean leave-one-out error; {len(bad)} of {len(consistency)} pairs "
             f"over {SUCCESS_PX:g} px by both:\n",
             "| pair | LOO homography px | LOO thin-plate px | " + " | ".join(f"{m} px" for m in methods) + " |",
             "|" + " --- |" * (3 + len(methods))]
    for key in bad:
        errs = [next(r[2] for r in rows[m] if (r[0], r[1]) == key) for m in methods]
        lines.append(f"| {key[0]}/{key[1]} | {consistency[key][0]:.2f} | {consistency[key][1]:.2f} | "
                     + " | ".join(f"{e:.2f}" for e in errs) + " |")
    rest = [f"{m} {100.0 * np.mean([r[2] < SUCCESS_PX for r in rows[m] if not loose((r[0], r[1]))]):.0f} %"
            for m in methods] if len(bad) < len(consistency) else []
    if rest:
        lines.append(f"\nSuccess on the other {len(consistency) - len(bad)} pairs: " + ", ".join(rest))
    return "\n".join(lines)


def save_figure(out: Path, a, b, transform, match) -> None:
    from reglib.dense import warp_image
    from reglib.visualize import draw_matches, overlay

    canvas = draw_matches(a, b, match, max_lines=400)
    if transform is not None:
        warped, _ = warp_image(b, transform, a.shape[:2])
        blend = overlay(a, warped)
        pad = np.zeros((canvas.shape[0], blend.shape[1], 3), np.uint8)
        pad[:blend.shape[0]] = blend
        canvas = np.concatenate([canvas, pad], axis=1)
    scale = min(1.0, 1800.0 / canvas.shape[1])
    if scale < 1.0:
        canvas = cv2.resize(canvas, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), cv2.cvtColor(canvas, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="../shared/data", type=Path)
    ap.add_argument("--quick", action="store_true", help="first pair of every kind only")
    ap.add_argument("--kinds", default="", help="comma-separated kind names (e.g. MR_PET,Retina)")
    ap.add_argument("--methods", default="", help=f"any of {list(ALL_METHODS)} (default: all that run here)")
    ap.add_argument("--detect", default="{}", help="JSON options of detect_multimodal")
    ap.add_argument("--match", default="{}", help="JSON options of match_multimodal")
    ap.add_argument("--filter", default="{}", help="JSON options of filter_matches (multimodal methods)")
    ap.add_argument("--figures", action="store_true", help="write benchmarks/figures/multimodal_*.jpg")
    ap.add_argument("--figure-method", default="mm_fit", help="method whose result is drawn")
    ap.add_argument("--verbose", action="store_true", help="one line per pair")
    args = ap.parse_args(argv)
    args.detect, args.match, args.filter = json.loads(args.detect), json.loads(args.match), json.loads(args.filter)
    methods = [m for m in args.methods.split(",") if m] or list(DEFAULT_METHODS)
    if not args.methods and "multimodal" in FEATURES:
        methods.insert(len(MM_METHODS), "pipeline_mm")
    unknown = [m for m in methods if m not in ALL_METHODS]
    if unknown:
        ap.error(f"unknown methods {unknown}; choose from {list(ALL_METHODS)}")
    kinds = {k for k in args.kinds.split(",") if k} or None
    pairs = load_pairs(args.data, kinds, args.quick)
    if not pairs:
        ap.error(f"no pairs under {args.data / 'multimodal'}")
    rows: dict[str, list] = {m: [] for m in methods}
    consistency: dict[tuple[str, str], tuple[float, float]] = {}  # landmarks' leave-one-out (H, TPS) per pair
    confidences: dict[str, list[tuple[float, float]]] = {}  # (confidence summary mean, error) of pipeline runs
    fig_pairs = {"Medica/MR_PET": "MRI_PET_1", "Remote/SAR_Optical": "SO1", "Medica/Retina": "Retina_27",
                 "Remote/Map_Optical": "MO1"}
    for kind, name, path in pairs:
        a, b = read(path / "a.png"), read(path / "b.png")
        land = np.loadtxt(path / "landmarks.txt", comments="#").reshape(-1, 4)
        loo = landmark_consistency(land)
        consistency[(kind, name)] = loo
        line = [f"{kind}/{name}", f"landmarks-LOO={loo[0]:.1f}/{loo[1]:.1f}px"]
        needs_mm = any(m in MM_METHODS + ("auto",) for m in methods)
        mm_pair = MultimodalPair(a, b, args.detect, args.match) if needs_mm else None
        done: dict[str, tuple] = {}  # "auto" and "sift" share one SIFT run (its seconds count for both)

        def timed(method: str, a=a, b=b, done=done) -> tuple:
            if method not in done:
                t0 = clock()
                transform, match = run(method, a, b, args)
                done[method] = (transform, match, clock() - t0)
            return done[method]

        for m in methods:
            if m in MM_METHODS:
                transform, match, sec = run_multimodal(mm_pair, m, args.filter)
            elif m == "auto":
                transform, match, sec = timed("sift")
                if match.reason is not None or match.n_inliers < AUTO_MIN_INLIERS:
                    transform, match, mm_sec = run_multimodal(mm_pair, "mm_fit", args.filter)
                    sec = sec + mm_sec
            else:
                transform, match, sec = timed(m)
            err = pair_error(transform, land)
            rows[m].append((kind, name, err, sec))
            summary = getattr(match, "confidence_summary", None)
            if summary:
                confidences.setdefault(m, []).append((summary["mean"], err))
            line.append(f"{m}={err:.2f}px/{sec[0]:.2f}s/{sec[1]:.2f}cpu")
            if args.figures and m == args.figure_method and fig_pairs.get(kind) == name and match is not None:
                tag = kind.split("/")[1].lower()
                save_figure(Path(__file__).parent / "figures" / f"multimodal_{tag}.jpg", a, b, transform, match)
        if args.verbose:
            print("  ".join(line), flush=True)
    kind_list = sorted({k for k, _, _ in pairs})
    print(f"\n{len(pairs)} pairs; success = mean landmark error < {SUCCESS_PX:g} px; "
          f"cells: success % / median error px / median wall s / median CPU s per pair")
    print(f"multimodal options: detect={args.detect} match={args.match} filter={args.filter}\n")
    print(table(rows, methods, kind_list))
    print(consistency_report(rows, methods, consistency))
    for m, vals in confidences.items():
        conf, err = np.array(vals).T
        ok = err < SUCCESS_PX
        print(f"\n{m}: confidence summary (mean) {np.median(conf[ok]) if ok.any() else float('nan'):.3f} median on "
              f"successes, {np.median(conf[~ok]) if (~ok).any() else float('nan'):.3f} on failures; ROC AUC "
              f"(failures low) {roc_auc(conf, ~ok):.3f}; pairs with confidence >= 0.5: {int((conf >= 0.5).sum())}, "
              f"{int((ok & (conf >= 0.5)).sum())} of them successes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
