"""Image pipeline benchmark: reglib.match_images against OpenCV DIS, DeepFlow, TV-L1, elastix and MAGSAC++.

Sections (all print markdown tables):

0. families   Dense flow end-point error on two families of synthetic pairs with exact per-pixel
              ground truth (``_synthetic_pairs.py``): the current one (``make_pairs``: 4 bumps, ratio
              test 0.9) and the harder one (``make_hard_pairs``: 8 bumps of up to 7 % of the image
              size each, similarity up to 25 degrees and 0.8-1.25, stronger gain / gamma / noise,
              ratio test 0.9 / 0.95 / none, plus pairs at 2x scale and at 90 degrees). Per family and
              method: mean EPE (the mean over pairs of each pair's mean EPE), median, worst pair,
              share of pairs under 1 px and 3 px, share of points under 3 px, median ms; a per-pair
              table; and how well reglib's confidence report predicts its own error (ROC AUC of the
              summary against "pair mean EPE > 3 px", and the share of points with confidence
              >= 0.5 within 3 px). Peers on the same pairs in the same run: OpenCV DIS (medium),
              DeepFlow and TV-L1 (opencv-contrib), elastix (itk-elastix: default affine + B-spline
              maps, and a tuned rigid -> affine -> B-spline variant; settings in ``ELASTIX_TUNED``).
              ``--seeds 0 1 2 3 4`` adds reglib's family means per ``rng`` seed.

1. synthetic  Non-rigid pairs with exact ground truth from scikit-image's bundled photographs
              (``_synthetic_pairs.py``): inlier precision / recall / F1 on the SIFT putatives (loose
              ratio test 0.9, and none: every nearest neighbour) and flow end-point error over every
              pixel of a whose true position falls inside b.
2. graf       Oxford graffiti 1-2, 1-3, 1-4 (ground-truth homographies; a match is true within 3 px).
3. labelled   church, retina, remote_sensing: the labelled putatives through our estimator, and the
              whole pipeline's transform scored against the labels.
4. timing     End-to-end match_images on two 512x768 (W x H) images against bare OpenCV SIFT
              extraction + brute-force k-NN matching, in one run (dense off, on, and on with dense_detail).
5. flow       dense_flow on a 1-megapixel grid against evaluating the transform at every pixel.
6. stain      Stain-like pairs (``make_stain_pairs``): scikit-image's ``immunohistochemistry`` section split
              by colour deconvolution into an H&E-like and an H-DAB-like rendering, b's warped
              non-rigidly (6 bumps of 2-8 % of the size, rotation up to 15 degrees) with the fine
              structure of another section (a few px of cell-scale jitter). 12 training seeds (the
              dense stage's constants were chosen on them) and 12 validation seeds never tuned on.
              Per pair: ``match_images(a, b, features="auto", rng=0)`` scored by
              :func:`reglib._evaluate.evaluate` on 80 landmarks: rTRE (median TRE over b's diagonal;
              success < 0.01), whether it answers converged, the dense outcome, seconds.
7. wide       The wider generator of issue 27 (``make_wide_pairs``): b = a through a backward map of a
              similarity (up to 25 degrees, 0.8-1.25, 5 % shift) and 8 bumps (widths 12-30 %) whose
              displacement components are N(0, s), s = 2.3 / 4.5 / 6.8 % of the size, no bound on the
              field's derivative (one-to-one: smallest Jacobian determinant > 0.005), ratio test 0.9 /
              none / 0.95; 27 training seeds (9000-9026) and 27 validation seeds (9100-9126, never tuned
              on). Per pair and family: mean EPE, share of points within 3 px, worst pair; for each pair over
              3 px by default, the putatives where the sparse fit alone is over 10 px off, and how many
              of them are correct and kept.
8. he         H&E against an immunostain (``make_he_pair``, 900 x 660 px): the same section rendered as H&E
              (haematoxylin in every nucleus, eosin in all the tissue; image b, warped as in section 6 on an
              empty slide's white) and as one immunostain (a pale counterstain, DAB in a few cells; image a).
              12 training seeds (5100-5111) and 12 validation seeds (7100-7111, never tuned on); the table of
              section 6, and the failures answered ``converged=True``.

Usage (from the project root)::

    .venv/bin/python benchmarks/bench_images.py                 # all sections, ~20 minutes (elastix is slow)
    .venv/bin/python benchmarks/bench_images.py --sections families --quick      # ~3 minutes
    .venv/bin/python benchmarks/bench_images.py --sections families --peers dis --seeds 0 1 2 3 4
    .venv/bin/python benchmarks/bench_images.py --sections synthetic --pairs 20
    .venv/bin/python benchmarks/bench_images.py --data ../shared/data --no-deepflow
    .venv/bin/python benchmarks/bench_images.py --sections stain                  # ~2 minutes
    .venv/bin/python benchmarks/bench_images.py --sections wide                   # ~6 minutes
    .venv/bin/python benchmarks/bench_images.py --sections he --stain-peers      # ~2 minutes, no peers

Data for sections 2-4: ``--data`` (default ``../shared/data``; see its README for the sources).
Not run by CI.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _stats import roc_auc
from _synthetic_pairs import (
    HE_TRAIN_SEEDS,
    HE_VALIDATION_SEEDS,
    STAIN_TRAIN_SEEDS,
    STAIN_VALIDATION_SEEDS,
    WIDE_FRESH_SEEDS,
    WIDE_POOL_SEEDS,
    WIDE_TRAIN_SEEDS,
    WIDE_VALIDATION_SEEDS,
    Pair,
    landmarks,
    make_hard_pairs,
    make_he_pair,
    make_pairs,
    make_stain_pair,
    make_wide_pairs,
)

from reglib import dense_flow, evaluate, filter_matches, match_images
from reglib._transforms import KernelWarp
from reglib.dense import texture_map
from reglib.features import detect_sift, match_descriptors, to_gray_uint8
from reglib.io import read_image


def prf(kept: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    tp = float(np.count_nonzero(kept & truth))
    p = tp / max(1, np.count_nonzero(kept))
    r = tp / max(1, np.count_nonzero(truth))
    f = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return p, r, f


def epe_stats(flow: np.ndarray, true: np.ndarray, valid: np.ndarray) -> tuple[float, float, float]:
    e = np.linalg.norm(flow.astype(np.float64) - true, axis=2)[valid]
    return float(e.mean()), float(np.median(e)), float(np.mean(e < 3.0))


def homography_flow(hmat: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    h, w = shape
    ys, xs = np.mgrid[0:h, 0:w]
    p = np.c_[xs.ravel(), ys.ravel(), np.ones(h * w)]
    q = p @ hmat.T
    q = q[:, :2] / q[:, 2:3]
    return (q - p[:, :2]).reshape(h, w, 2)


def magsac(src: np.ndarray, dst: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray | None]:
    if len(src) < 8:
        return np.zeros(len(src), bool), None
    s, d = src.astype(np.float32), dst.astype(np.float32)
    if kind == "H":
        mat, mask = cv2.findHomography(s, d, cv2.USAC_MAGSAC, 3.0, maxIters=10000, confidence=0.999)
    else:
        mat, mask = cv2.findFundamentalMat(s, d, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)
    if mask is None:
        return np.zeros(len(src), bool), None
    return mask.ravel().astype(bool), mat


def table(headers: list[str], rows: list[list]) -> str:
    def fmt(v):
        return f"{v:.3f}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


# --------------------------------------------------------------------------------- synthetic
def bench_synthetic(args: argparse.Namespace) -> None:
    t0 = time.perf_counter()
    pairs = make_pairs(args.pairs, seed=args.seed, max_side=args.max_side)
    print(f"\n## Synthetic non-rigid pairs: {len(pairs)} pairs over {len({p.name for p in pairs})} images "
          f"(max side {args.max_side}, generated in {time.perf_counter() - t0:.0f} s)\n")
    inl_rows: dict[tuple[str, float], list] = {}
    flow_rows: dict[str, list] = {}
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    deep = None if args.no_deepflow else cv2.optflow.createOptFlow_DeepFlow()
    for pair in pairs:
        h, w = pair.a.shape[:2]
        true = pair.true_flow()
        valid = ((pair.a.shape[1] - 1 >= true[..., 0] + np.arange(w)[None]) & (true[..., 0] + np.arange(w)[None] >= 0)
                 & (h - 1 >= true[..., 1] + np.arange(h)[:, None]) & (true[..., 1] + np.arange(h)[:, None] >= 0))
        for ratio in (0.9, 1.0):
            for method in ("l2e", "vfc"):
                t = time.perf_counter()
                m = match_images(pair.a, pair.b, method=method, rng=0,
                                 options={"ratio": ratio, "dense": method == "l2e"})
                ms = (time.perf_counter() - t) * 1000
                truth = np.linalg.norm(pair.forward(m.src) - m.dst, axis=1) < 3.0
                inl_rows.setdefault((f"reglib {method.upper()}", ratio), []).append(
                    (*prf(m.inliers, truth), truth.mean(), m.n_matches, ms))
                if ratio == 0.9:
                    flow = dense_flow(m.transform, (h, w))
                    flow_rows.setdefault(f"reglib {method.upper()}" + (" + dense" if method == "l2e" else " (sparse)"),
                                         []).append((*epe_stats(flow, true, valid), ms))
                if method == "l2e":
                    src, dst = m.src, m.dst
            for kind in ("H", "F"):
                t = time.perf_counter()
                mask, mat = magsac(src, dst, kind)
                ms = (time.perf_counter() - t) * 1000
                truth = np.linalg.norm(pair.forward(src) - dst, axis=1) < 3.0
                inl_rows.setdefault((f"MAGSAC++ {'homography' if kind == 'H' else 'fundamental'}", ratio),
                                    []).append((*prf(mask, truth), truth.mean(), len(src), ms))
                if kind == "H" and ratio == 0.9:
                    flow = homography_flow(mat, (h, w)) if mat is not None else np.zeros((h, w, 2))
                    flow_rows.setdefault("MAGSAC++ homography", []).append((*epe_stats(flow, true, valid), ms))
        ga, gb = to_gray_uint8(pair.a), to_gray_uint8(pair.b)
        t = time.perf_counter()
        flow = dis.calc(ga, gb, None)
        flow_rows.setdefault("OpenCV DIS (medium)", []).append((*epe_stats(flow, true, valid),
                                                                (time.perf_counter() - t) * 1000))
        if deep is not None:
            t = time.perf_counter()
            flow = deep.calc(ga, gb, None)
            flow_rows.setdefault("OpenCV DeepFlow", []).append((*epe_stats(flow, true, valid),
                                                                (time.perf_counter() - t) * 1000))
        print(f"  {pair.name}: done", file=sys.stderr)
    print("### Inlier identification on the SIFT putatives (mean over pairs; true = within 3 px of T(p))\n")
    rows = []
    for (name, ratio), vals in sorted(inl_rows.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        v = np.array(vals)
        rows.append([name, "none" if ratio == 1.0 else f"{ratio}", float(v[:, 3].mean()), int(v[:, 4].mean()),
                     float(v[:, 0].mean()), float(v[:, 1].mean()), float(v[:, 2].mean()), float(v[:, 2].min()),
                     f"{np.median(v[:, 5]):.0f}"])
    print(table(["method", "ratio test", "true share", "putatives", "precision", "recall", "F1", "worst F1",
                 "median ms"], rows))
    print("\n(reglib L2E ran with dense refinement on, VFC with it off; the inlier set is the sparse stage's "
          "either way; ms: whole match_images incl. SIFT.)")
    print("\n### Dense flow end-point error (px, over pixels of a landing inside b; ratio 0.9)\n")
    rows = []
    for name, vals in flow_rows.items():
        v = np.array(vals)
        rows.append([name, float(v[:, 0].mean()), float(np.median(v[:, 1])), float(v[:, 2].mean()),
                     float(v[:, 0].max()), f"{np.median(v[:, 3]):.0f}"])
    print(table(["method", "mean EPE", "median EPE", "share < 3 px", "worst pair mean EPE", "median ms"], rows))
    print("\n(reglib ms: whole match_images incl. SIFT; MAGSAC++ ms: the estimator alone on our putatives; "
          "DIS / DeepFlow ms: the flow alone.)")


# --------------------------------------------------------------------------------- families
PEERS = ("dis", "deepflow", "tvl1", "elastix", "elastix_rigid")
SLOW_PEERS = ("tvl1", "elastix", "elastix_rigid")
PEER_NAMES = {"dis": "OpenCV DIS (medium)", "deepflow": "OpenCV DeepFlow", "tvl1": "OpenCV TV-L1 (optflow)",
              "elastix": "elastix, default affine + B-spline maps",
              "elastix_rigid": "elastix, tuned rigid + affine + B-spline"}
# The tuned elastix variant (the best we found on these pairs): a rigid (Euler) stage first, started at the
# centres of gravity, so that the affine stage starts inside its capture range; normalized correlation (one
# modality, gain / gamma change); more resolutions for the linear stages and a coarser final B-spline grid
# (these deformations are smooth; the default 10 px grid fits noise); 4096 samples per iteration. 256 iterations per
# stage as in the default maps (500 gained a little on the pairs we tried and doubled the time).
ELASTIX_TUNED = {
    "rigid": {"Metric": "AdvancedNormalizedCorrelation", "NumberOfResolutions": "5",
              "MaximumNumberOfIterations": "256", "AutomaticTransformInitialization": "true",
              "AutomaticTransformInitializationMethod": "CenterOfGravity", "NumberOfSpatialSamples": "4096"},
    "affine": {"Metric": "AdvancedNormalizedCorrelation", "NumberOfResolutions": "4",
               "MaximumNumberOfIterations": "256", "NumberOfSpatialSamples": "4096"},
    "bspline": {"Metric": ("AdvancedNormalizedCorrelation", "TransformBendingEnergyPenalty"),
                "NumberOfResolutions": "4", "FinalGridSpacingInPhysicalUnits": "32",
                "MaximumNumberOfIterations": "256", "NumberOfSpatialSamples": "4096"},
}


def _valid(pair: Pair, true: np.ndarray) -> np.ndarray:
    """Pixels of a whose true position lies inside b (b has a's size)."""
    h, w = pair.b.shape[:2]
    tx = true[..., 0] + np.arange(true.shape[1])[None]
    ty = true[..., 1] + np.arange(true.shape[0])[:, None]
    return (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)


TEXTURE_STD = 2.0  # grey levels (uint8): an 11 x 11 patch of a flatter than this shows no motion
TEXTURE_REACH = 16  # px: pixels this far from any textured patch centre (one dense grid step) count as near it


def _near_texture(gray: np.ndarray) -> np.ndarray:
    """(H, W) bool: within TEXTURE_REACH px of a pixel whose 11 x 11 patch of ``gray`` has a std >= TEXTURE_STD
    (the patch std of the dense stage's own texture test, ``reglib.dense.texture_map``, half-size 5).

    Farther from texture (a clear sky, a flat wall) the images do not show where a pixel went: any
    flow there is an extrapolation, whatever the method.
    """
    flat = (texture_map(gray.astype(np.float32)[:, :, None], 5) < TEXTURE_STD).astype(np.uint8)
    return cv2.distanceTransform(flat, cv2.DIST_L2, 5) <= TEXTURE_REACH


def _elastix_flow(ga: np.ndarray, gb: np.ndarray, variant: str, max_iter: int) -> np.ndarray:
    """Forward flow a -> b from elastix (fixed = a, moving = b: its transform maps a's points into b)."""
    import itk

    # itk may view the arrays' memory: keep them alive for the whole registration
    arr_a, arr_b = np.ascontiguousarray(ga, np.float32), np.ascontiguousarray(gb, np.float32)
    fixed, moving = itk.GetImageFromArray(arr_a), itk.GetImageFromArray(arr_b)
    params = itk.ParameterObject.New()
    stages = ("affine", "bspline") if variant == "elastix" else ("rigid", "affine", "bspline")
    for stage in stages:
        pm = params.GetDefaultParameterMap(stage, 4)
        if variant != "elastix":
            for key, value in ELASTIX_TUNED[stage].items():
                pm[key] = value if isinstance(value, tuple) else (value,)
        pm["MaximumNumberOfIterations"] = (str(min(int(pm["MaximumNumberOfIterations"][0]), max_iter)),)
        params.AddParameterMap(pm)
    # (no number_of_threads: with a B-spline stage it crashes itk-elastix 0.25.4; elastix uses every core)
    _, result = itk.elastix_registration_method(fixed, moving, parameter_object=params, log_to_console=False)
    with tempfile.TemporaryDirectory() as tmp:  # transformix writes deformationField.nii into its output folder
        field = itk.transformix_deformation_field(moving, result, output_directory=tmp)
    flow = np.array(itk.GetArrayFromImage(field), np.float64)
    del arr_a, arr_b
    return flow


def _peer_flow(peer: str, ga: np.ndarray, gb: np.ndarray, max_iter: int) -> np.ndarray:
    if peer == "dis":
        return cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(ga, gb, None)
    if peer == "deepflow":
        return cv2.optflow.createOptFlow_DeepFlow().calc(ga, gb, None)
    if peer == "tvl1":
        # 3 warps, 10 inner x 3 outer iterations (OpenCV's defaults 5, 30 x 10 took 80-160 s a pair here, same EPE)
        tv = cv2.optflow.DualTVL1OpticalFlow_create()
        tv.setWarpingsNumber(3)
        tv.setInnerIterations(10)
        tv.setOuterIterations(3)
        return tv.calc(ga, gb, None)
    return _elastix_flow(ga, gb, peer, max_iter)


def _family_rows(results: dict[str, list[dict]]) -> list[list]:
    rows = []
    for name, vals in results.items():
        means = np.array([v["mean"] for v in vals])
        rows.append([name, float(means.mean()), float(np.median([v["median"] for v in vals])), float(means.max()),
                     f"{np.mean(means < 1.0):.0%}", f"{np.mean(means < 3.0):.0%}",
                     float(np.mean([v["under3"] for v in vals])),
                     float(np.mean([v.get("under3_near", np.nan) for v in vals])),
                     f"{np.median([v['ms'] for v in vals]):.0f}"])
    return rows


def _confidence_figure(shown: list[tuple], folder: Path) -> None:
    """images_confidence.png: for the harder family's median and worst pair, a | EPE (0-5 px) | confidence."""
    rows = []
    for mean, label, ga, err, conf in (shown[len(shown) // 2], shown[-1]):
        grey = cv2.cvtColor(ga, cv2.COLOR_GRAY2BGR)
        e = cv2.applyColorMap(np.clip(err / 5.0 * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
        c = cv2.applyColorMap(np.round(conf * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
        row = np.hstack([grey, e, c])
        cv2.putText(row, f"{label}: mean EPE {mean:.2f} px | EPE 0-5 px | confidence 0-1", (8, 22),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2, cv2.LINE_AA)
        rows.append(row)
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "images_confidence.png"), np.vstack(rows))
    print(f"\n(figure: {folder / 'images_confidence.png'}: the harder family's median and worst pair for reglib)")


def bench_families(args: argparse.Namespace) -> None:
    n_cur, n_hard, n_special = (8, 9, 2) if args.quick else (20, 24, 4)
    t0 = time.perf_counter()
    families = {"current": make_pairs(n_cur, seed=args.seed, max_side=args.max_side),
                "harder": make_hard_pairs(n_hard, seed=1000 + args.seed, max_side=args.max_side, n_special=n_special)}
    peers = [p for p in args.peers if p in PEERS]
    elastix_iter = min(args.elastix_iter, 128) if args.quick else args.elastix_iter
    print(f"\n## Dense flow on two synthetic families ({len(families['current'])} + {len(families['harder'])} "
          f"pairs, max side {args.max_side}, generated in {time.perf_counter() - t0:.0f} s"
          f"{', quick' if args.quick else ''})\n")
    summaries, pair_epes, conf_pixels, err_pixels = [], [], [], []
    shown: list[tuple] = []
    cache = json.loads(Path(args.peer_cache).read_text()) if args.peer_cache and Path(args.peer_cache).exists() else {}
    n_cached = 0
    seed_means: dict[int, dict[str, list[float]]] = {}
    for fam, pairs in families.items():
        results: dict[str, list[dict]] = {}
        per_pair = []
        for i, pair in enumerate(pairs):
            true = pair.true_flow()
            valid = _valid(pair, true)
            ga, gb = to_gray_uint8(pair.a), to_gray_uint8(pair.b)
            near = _near_texture(ga)[valid]

            def score(flow: np.ndarray, ms: float, true: np.ndarray = true, valid: np.ndarray = valid,
                      near: np.ndarray = near) -> dict:
                e = np.linalg.norm(flow.astype(np.float64) - true, axis=2)[valid]
                return {"mean": float(e.mean()), "median": float(np.median(e)), "under3": float(np.mean(e < 3.0)),
                        "under3_near": float(np.mean(e[near] < 3.0)) if near.any() else 1.0,
                        "far": float(np.mean(~near)),
                        "far_of_bad": float(np.mean(~near[e >= 3.0])) if (e >= 3.0).any() else 0.0,
                        "ms": ms, "err": e}

            t = time.perf_counter()
            m = match_images(pair.a, pair.b, rng=0, options={"ratio": pair.ratio})
            ms = (time.perf_counter() - t) * 1000
            r = score(dense_flow(m.transform, (pair.a.shape[0], pair.a.shape[1])), ms)
            results.setdefault("reglib (match_images + dense_flow)", []).append(r)
            summary = m.confidence_summary or {"mean": 0.0, "supported_share": 0.0}
            summaries.append(summary)
            pair_epes.append(r["mean"])
            conf_pixels.append(m.confidence[valid])
            err_pixels.append(r["err"])
            if fam == "harder":
                err_map = np.zeros(valid.shape)
                err_map[valid] = r["err"]
                shown.append((r["mean"], f"{pair.name} ({pair.kind}, ratio {pair.ratio})", ga, err_map, m.confidence))
            row = [fam, i, pair.name, pair.kind, "none" if pair.ratio == 1.0 else f"{pair.ratio}", r["mean"],
                   r["under3"], r["far"], r["far_of_bad"], summary["mean"], summary["supported_share"]]
            for peer in peers:
                if peer in SLOW_PEERS and i % args.peer_every:
                    row.append("")
                    continue
                key = f"{fam}/{i}/{pair.name}/{pair.kind}/{peer}" + (f"/{elastix_iter}" if "elastix" in peer else "")
                pr = cache.get(key)
                if pr is None:
                    t = time.perf_counter()
                    try:
                        flow = _peer_flow(peer, ga, gb, elastix_iter)
                        pr = score(flow, (time.perf_counter() - t) * 1000)
                    except Exception as exc:  # noqa: BLE001  (a peer that fails scores as no motion, and says why)
                        print(f"  {peer} failed on {pair.name}: {exc}", file=sys.stderr)
                        pr = score(np.zeros(true.shape), (time.perf_counter() - t) * 1000)
                    pr.pop("err")
                    if args.peer_cache:
                        cache[key] = pr
                        Path(args.peer_cache).write_text(json.dumps(cache))
                else:
                    n_cached += 1
                results.setdefault(PEER_NAMES[peer], []).append(pr)
                if peer == next((p for p in peers if p in SLOW_PEERS), None) and args.peer_every > 1:
                    results.setdefault(f"reglib on the TV-L1 / elastix pairs (every {args.peer_every}th)",
                                       []).append(r)
                row.append(pr["mean"])
            per_pair.append(row)
            for seed in args.seeds:
                ms_ = match_images(pair.a, pair.b, rng=seed, options={"ratio": pair.ratio})
                e = np.linalg.norm(dense_flow(ms_.transform, pair.a.shape[:2]).astype(np.float64) - true, axis=2)[valid]
                seed_means.setdefault(seed, {}).setdefault(fam, []).append(float(e.mean()))
            print(f"  {fam} {i} {pair.name}: reglib {r['mean']:.2f} px", file=sys.stderr)
        title = ("current family (make_pairs: 4 bumps, ratio 0.9)" if fam == "current" else
                 "harder family (make_hard_pairs: 8 bumps up to 7 % each, ratio 0.9 / 0.95 / none, 2x scale, 90 deg)")
        print(f"### {title}\n")
        print(table(["method", "mean EPE", "median EPE", "worst pair mean EPE", "pairs < 1 px", "pairs < 3 px",
                     "share of points < 3 px", f"... of those within {TEXTURE_REACH} px of texture", "median ms"],
                    _family_rows(results)))
        print()
        print(table(["family", "pair", "image", "kind", "ratio test", "reglib EPE", "reglib points < 3 px",
                     "points far from texture", "... of reglib's points >= 3 px", "conf mean", "conf supported"]
                    + [f"{p} EPE" for p in peers], per_pair))
        ours = results["reglib (match_images + dense_flow)"]
        print(f"\n(points far from texture: farther than {TEXTURE_REACH} px from any 11 x 11 patch of a with a std of "
              f"{TEXTURE_STD:g} grey levels or more, where the images do not show the motion: "
              f"{np.mean([v['far'] for v in ours]):.1%} of the points, "
              f"{np.mean([v['far_of_bad'] for v in ours if v['under3'] < 1.0] or [0.0]):.0%} of reglib's points "
              "over 3 px on the pairs that have any)")
        print()
    if args.peer_every > 1 and any(p in SLOW_PEERS for p in peers):
        print(f"(TV-L1 and elastix ran on every {args.peer_every}th pair of each family, to bound the run's time; the "
              "'reglib on the TV-L1 / elastix pairs' row is reglib on exactly those pairs.)")
    if n_cached:
        print(f"({n_cached} peer results were read from the cache {args.peer_cache}, computed on the same pairs and "
              "settings earlier; their ms are from that run.)")
    print("(EPE: px over the pixels of a whose true position is inside b; a family's mean EPE is the mean over "
          "pairs of each pair's mean; share of points: mean over pairs. reglib ms: whole match_images incl. SIFT "
          "and the confidence map; peers' ms: the flow alone. Failed peer runs score as zero flow.)")
    pair_means = np.array(pair_epes)
    bad = pair_means > 3.0
    conf = np.concatenate(conf_pixels)
    err = np.concatenate(err_pixels)
    hi = conf >= 0.5
    print("\n### reglib's confidence report against its own error (both families)\n")
    # (with no pair over 3 px the first AUC is undefined; the 1 px split still says whether the summary ranks pairs)
    rows = [[key, roc_auc(np.array([s[key] for s in summaries]), bad),
             roc_auc(np.array([s[key] for s in summaries]), pair_means > 1.0)] for key in ("mean", "supported_share")]
    print(table(["summary", "ROC AUC (pairs with mean EPE > 3 px vs the rest)",
                 "ROC AUC (pairs with mean EPE > 1 px vs the rest)"], rows))
    print(f"\n{int(bad.sum())} of {len(bad)} pairs over 3 px; points with confidence >= 0.5: {hi.mean():.1%} of all, "
          f"{np.mean(err[hi] < 3.0) if hi.any() else float('nan'):.4f} of them within 3 px "
          f"({np.mean(err[~hi] < 3.0) if (~hi).any() else float('nan'):.4f} of the rest).")
    if args.figures and shown:
        _confidence_figure(sorted(shown, key=lambda v: v[0]), Path(args.figures))
    if seed_means:
        print("\n### reglib family mean EPE per rng seed\n")
        rows = [[seed, float(np.mean(v["current"])), float(np.mean(v["harder"]))] for seed, v in seed_means.items()]
        spread = [max(r[k] for r in rows) - min(r[k] for r in rows) for k in (1, 2)]
        print(table(["seed", "current mean EPE", "harder mean EPE"], rows))
        print(f"\nspread (max - min): current {spread[0]:.3f} px, harder {spread[1]:.3f} px")


# ------------------------------------------------------------------------------------ graf
def bench_graf(args: argparse.Namespace) -> None:
    root = Path(args.data) / "image_pairs" / "graf"
    if not root.is_dir():
        print(f"\n## graf: skipped, no {root}")
        return
    print("\n## Oxford graf (true = within 3 px of the ground-truth homography), ratio 0.8\n")
    a = read_image(root / "img1.png")
    rows = []
    for k in (2, 3, 4):
        b = read_image(root / f"img{k}.png")
        hmat = np.loadtxt(root / f"H1to{k}p")
        m = match_images(a, b, rng=0, options={"dense": False})
        q = np.c_[m.src, np.ones(len(m.src))] @ hmat.T
        truth = np.linalg.norm(q[:, :2] / q[:, 2:] - m.dst, axis=1) < 3.0
        ours = prf(m.inliers, truth)
        vfc = filter_matches(m.src, m.dst, method="vfc", rng=0)
        hm, _ = magsac(m.src, m.dst, "H")
        fm, _ = magsac(m.src, m.dst, "F")
        rows.append([f"1-{k}", m.n_matches, int(truth.sum()), *ours, prf(vfc.inliers, truth)[2], *prf(hm, truth),
                     prf(fm, truth)[2], ours[2] - prf(hm, truth)[2]])
    print(table(["pair", "putatives", "true", "L2E P", "L2E R", "L2E F1", "VFC F1", "MAGSAC++ H P",
                 "MAGSAC++ H R", "MAGSAC++ H F1", "MAGSAC++ F F1", "F1 L2E - H"], rows))


# -------------------------------------------------------------------------------- labelled
def bench_labelled(args: argparse.Namespace) -> None:
    root = Path(args.data) / "image_pairs"
    sets = {"church": ("church1.jpg", "church2.jpg"), "retina": ("retina_a.jpg", "retina_b.jpg"),
            "remote_sensing": ("a.bmp", "b.bmp")}
    rows = []
    for name, (fa, fb) in sets.items():
        d = root / name
        if not d.is_dir():
            continue
        with np.load(d / "putative_matches.npz") as z:
            src, dst, correct = z["src"], z["dst"], z["correct"]
        truth = np.zeros(len(src), bool)
        truth[correct] = True
        est = filter_matches(src, dst, rng=0)
        hm, _ = magsac(src, dst, "H")
        fm, _ = magsac(src, dst, "F")
        t = time.perf_counter()
        m = match_images(d / fa, d / fb, rng=0)
        ms = (time.perf_counter() - t) * 1000
        near = np.linalg.norm(m.transform(src) - dst, axis=1) < 5.0
        rows.append([name, len(src), int(truth.sum()), *prf(est.inliers, truth), prf(hm, truth)[2], prf(fm, truth)[2],
                     m.n_matches, m.n_inliers, *prf(near, truth)[:2], f"{ms:.0f}"])
    if not rows:
        print(f"\n## labelled pairs: skipped, nothing under {root}")
        return
    print("\n## Labelled pairs: the given putatives through L2E (filter_matches), and the whole pipeline\n")
    print(table(["pair", "putatives", "true", "L2E P", "L2E R", "L2E F1", "MAGSAC++ H F1", "MAGSAC++ F F1",
                 "pipeline putatives", "pipeline inliers", "pipeline f: P (5 px)", "pipeline f: R (5 px)",
                 "pipeline ms"], rows))
    print("\n(pipeline f: a labelled putative counts as kept when the pipeline's final transform maps its src "
          "within 5 px of its dst.)")


# ---------------------------------------------------------------------------------- timing
def bench_timing(args: argparse.Namespace) -> None:
    church = Path(args.data) / "image_pairs" / "church"
    if church.is_dir():
        a, b = read_image(church / "church1.jpg"), read_image(church / "church2.jpg")
        label = "church1/church2 (512x768)"
    else:
        import skimage.data

        a = cv2.resize(skimage.data.astronaut(), (512, 768))
        b = cv2.warpAffine(a, cv2.getRotationMatrix2D((256, 384), 10, 1.05), (512, 768))
        label = "astronaut, 512x768, rotated copy"
    assert a.shape[:2] == (768, 512)

    def bare() -> None:
        ga, gb = to_gray_uint8(a), to_gray_uint8(b)
        sift = cv2.SIFT_create(nfeatures=4000)
        _, da = sift.detectAndCompute(ga, None)
        _, db = sift.detectAndCompute(gb, None)
        knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
        _ = [m for m, n in knn if m.distance < 0.8 * n.distance]

    def ours(dense: bool, **extra):
        return lambda: match_images(a, b, rng=0, options={"dense": dense, **extra})

    runs = {"bare OpenCV SIFT + BF k-NN + ratio": bare, "match_images, dense off": ours(False),
            "match_images, dense on": ours(True),
            "match_images, dense on, dense_detail=True": ours(True, dense_detail=True)}
    times: dict[str, list[float]] = {k: [] for k in runs}
    cpu: dict[str, list[float]] = {k: [] for k in runs}  # CPU time of this process, all threads
    for _ in range(args.repeat):
        for name, fn in runs.items():  # interleaved, so machine load hits all alike
            t, c = time.perf_counter(), time.process_time()
            fn()
            times[name].append((time.perf_counter() - t) * 1000)
            cpu[name].append((time.process_time() - c) * 1000)
    bare_name = "bare OpenCV SIFT + BF k-NN + ratio"
    base, base_cpu = float(np.median(times[bare_name])), float(np.median(cpu[bare_name]))
    m = match_images(a, b, rng=0)
    print(f"\n## End-to-end time on {label}, median of {args.repeat} (load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores)\n")
    rows = [[name, float(np.median(v)), float(np.median(v)) / base, float(np.median(cpu[name])),
             float(np.median(cpu[name])) / base_cpu] for name, v in times.items()]
    print(table(["run", "median ms", "x bare SIFT", "median CPU ms", "x bare SIFT (CPU)"], rows))
    print("\n(wall time is the measure; CPU time, summed over the process's threads, is shown because on a "
          "shared machine the wall-time ratio moves with the load)")
    print("\nStages of one dense run (ms): " + ", ".join(f"{k} {v:.0f}" for k, v in m.timings_ms.items()))
    # bare detection on our side, to show where time goes
    f = detect_sift(to_gray_uint8(a))
    t = time.perf_counter()
    match_descriptors(f.descriptors, f.descriptors)
    print(f"(our matching of {len(f.points)} x {len(f.points)} descriptors alone: "
          f"{(time.perf_counter() - t) * 1000:.0f} ms)")


def bench_flow(args: argparse.Namespace) -> None:
    """dense_flow on a 1-megapixel grid: time and error against evaluating the transform per pixel."""
    from reglib import fold_fraction

    pairs = make_pairs(3, seed=args.seed, max_side=1000)
    rows = []
    for pair in pairs:
        m = match_images(pair.a, pair.b, rng=0)
        shape = (1000, 1000)
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            flow = dense_flow(m.transform, shape)
            times.append((time.perf_counter() - t) * 1000)
        t = time.perf_counter()
        fold_fraction(m.transform, shape)
        fold_ms = (time.perf_counter() - t) * 1000
        ys, xs = np.mgrid[0:1000, 0:1000]
        p = np.c_[xs.ravel(), ys.ravel()].astype(float)
        t = time.perf_counter()
        exact = (m.transform(p) - p).reshape(1000, 1000, 2)
        exact_ms = (time.perf_counter() - t) * 1000
        rows.append([pair.name, m.transform.n_centers, float(np.median(times)), float(np.abs(flow - exact).max()),
                     exact_ms, fold_ms])
    print("\n## dense_flow on 1000 x 1000 pixels (transforms from match_images on synthetic pairs)\n")
    print(table(["pair", "centres", "dense_flow ms (median)", "max |error| px vs per-pixel", "per-pixel ms",
                 "fold_fraction ms"], rows))


STAIN_PEERS = ("elastix_rigid", "syn", "synra")
STAIN_PEER_NAMES = {"elastix_rigid": "elastix, rigid -> affine -> B-spline (ELASTIX_TUNED)",
                    "syn": "ANTsPy SyN, defaults", "synra": "ANTsPy SyNRA, defaults"}


def _sample_flow(flow: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points + flow`` at (K, 2) (x, y) points, the (H, W, 2) flow interpolated bilinearly."""
    from scipy.ndimage import map_coordinates

    coords = [points[:, 1], points[:, 0]]
    return points + np.stack([map_coordinates(flow[..., c], coords, order=1, mode="nearest") for c in (0, 1)], 1)


def _ants_points(ga: np.ndarray, gb: np.ndarray, kind: str, points: np.ndarray) -> np.ndarray:
    """(K, 2) points of a (x, y) mapped into b by ANTsPy (fixed = a, moving = b; ``kind`` "SyN" / "SyNRA").

    ANTs maps points the way opposite to images: the forward transforms, which pull the moving image
    into the fixed frame, take a fixed-frame point to its moving-frame position. An image from a numpy
    (H, W) array has its first physical axis along the rows, so (x, y) goes in as (y, x).
    """
    import ants
    import pandas as pd

    fixed = ants.from_numpy(np.ascontiguousarray(ga, np.float32))
    moving = ants.from_numpy(np.ascontiguousarray(gb, np.float32))
    reg = ants.registration(fixed=fixed, moving=moving, type_of_transform=kind, random_seed=0)
    table_in = pd.DataFrame({"x": points[:, 1], "y": points[:, 0]})
    out = ants.apply_transforms_to_points(2, table_in, reg["fwdtransforms"])
    return np.c_[out["y"].to_numpy(), out["x"].to_numpy()]


def peer_points(peer: str, a: np.ndarray, b: np.ndarray, points: np.ndarray, max_iter: int = 1000) -> np.ndarray:
    """A peer's image of a's (K, 2) points in b (:data:`STAIN_PEERS`), from grey float32 images."""
    ga, gb = (to_gray_uint8(x).astype(np.float32) for x in (a, b))
    if peer in ("syn", "synra"):
        return _ants_points(ga, gb, "SyN" if peer == "syn" else "SyNRA", points)
    return _sample_flow(_elastix_flow(ga, gb, peer, max_iter), points)


STAIN_FAMILIES = {"stain": ("Stain-like pairs (immunohistochemistry, colour deconvolution; match_images features=auto)",
                             make_stain_pair, STAIN_TRAIN_SEEDS, STAIN_VALIDATION_SEEDS),
                  "he": ("H&E against an immunostain (make_he_pair, 900 x 660 px; match_images features=auto)",
                         make_he_pair, HE_TRAIN_SEEDS, HE_VALIDATION_SEEDS)}


def _stain_peers(args: argparse.Namespace, summary: list, section: str = "stain") -> None:
    """The peers of :data:`STAIN_PEERS` named in ``args.stain_peers`` on both halves of a stain section's family
    (:data:`STAIN_FAMILIES`), one row each."""
    _, make, train, validation = STAIN_FAMILIES[section]
    for peer in args.stain_peers:
        for family, seeds in (("training", train), ("validation", validation)):
            rtre, times = [], []
            for seed in seeds:
                pair = make(seed)
                la, lb = landmarks(pair)
                t = time.perf_counter()
                mapped = peer_points(peer, pair.a, pair.b, la)
                times.append(time.perf_counter() - t)
                h, w = pair.b.shape[:2]
                tre = np.linalg.norm(mapped - lb, axis=1)
                rtre.append(float(np.median(tre)) / float(np.hypot(h, w)))
                print(f"  {section} {peer} {family} {seed}: rTRE {rtre[-1]:.4f}", file=sys.stderr)
            r = np.array(rtre)
            summary.append([f"{family}: {STAIN_PEER_NAMES[peer]}", float(np.mean(r < 0.01)), f"{np.median(r):.4f}",
                            f"{np.max(r):.4f}", "-", "-", "-", float(np.median(times))])


def bench_stain(args: argparse.Namespace, section: str = "stain") -> None:
    """Section 6: a stain family's training and validation halves (:data:`STAIN_FAMILIES`), scored by landmark
    rTRE; ``section`` "he" is section 8."""
    title, make, train, validation = STAIN_FAMILIES[section]
    print(f"\n## {title}\n")
    summary = []
    for family, seeds in (("training", train), ("validation", validation)):
        rows, rtre, rtre0, conv, times = [], [], [], [], []
        for seed in seeds:
            pair = make(seed)
            la, lb = landmarks(pair)
            t = time.perf_counter()
            m = match_images(pair.a, pair.b, features="auto", rng=0)
            times.append(time.perf_counter() - t)
            ev = evaluate(m.transform, la, lb, shape_b=pair.b.shape[:2])
            none = evaluate(KernelWarp.identity(2), la, lb, shape_b=pair.b.shape[:2])
            rtre.append(ev.rtre_median)
            rtre0.append(none.rtre_median)
            conv.append(m.converged)
            dense = (m.confidence_summary or {}).get("dense", "-")
            rows.append([pair.name, m.features, m.n_inliers, m.n_dense, dense, m.converged, m.reason or "-",
                         f"{ev.rtre_median:.4f}", f"{none.rtre_median:.4f}", ev.mean, times[-1]])
        print(f"### {family} ({len(seeds)} pairs, seeds {seeds[0]}-{seeds[-1]})\n")
        print(table(["pair", "features", "inliers", "n_dense", "dense", "converged", "reason", "rTRE median",
                     "no motion", "TRE mean px", "s"], rows))
        r, ok = np.array(rtre), np.array(rtre) < 0.01
        worse = np.array(rtre) > np.array(rtre0)
        cv = np.array(conv)
        summary.append([family, float(np.mean(ok)), f"{np.median(r):.4f}", f"{np.max(r):.4f}",
                        float(np.mean(cv[ok])) if ok.any() else 0.0, f"{int(np.count_nonzero(cv & ~ok))}",
                        int(np.count_nonzero(worse & cv)), float(np.median(times))])
        print()
    _stain_peers(args, summary, section)
    print(table(["family", "success (< 0.01)", "median rTRE", "worst rTRE", "converged among successes",
                 "failures answered converged", "worse than no motion yet converged", "median s"], summary))
    if args.stain_peers:
        print("\n(peers: grey float32 images, a fixed and b moving, elastix with at most 1000 iterations per stage; "
              "each peer's time in the same run on the same machine)")


def bench_he(args: argparse.Namespace) -> None:
    """Section 8: the H&E-like family (:func:`bench_stain` with ``section="he"``)."""
    bench_stain(args, "he")


def _missed_area(pair, true: np.ndarray) -> list:
    """For a pair the pipeline got wrong: the putatives where the sparse fit alone is over 10 px off the true field,
    how many of them are correct (within 3 px of it) and how many the filter kept."""
    m = match_images(pair.a, pair.b, rng=0, options={"ratio": pair.ratio, "dense": False})
    h, w = true.shape[:2]
    xi = np.clip(np.rint(m.src[:, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.rint(m.src[:, 1]).astype(int), 0, h - 1)
    at_true = m.src + true[yi, xi]
    missed = np.linalg.norm(m.transform(m.src) - at_true, axis=1) > 10.0
    correct = np.linalg.norm(m.dst - at_true, axis=1) < 3.0
    return [int(missed.sum()), int((missed & correct).sum()), int((missed & m.inliers).sum()),
            int((missed & m.inliers & correct).sum())]


# the wider generator's seed sets: constants were chosen on "training" and "pool", never on the other two
WIDE_FAMILIES = {"training": WIDE_TRAIN_SEEDS, "validation": WIDE_VALIDATION_SEEDS, "pool": WIDE_POOL_SEEDS,
                 "fresh": WIDE_FRESH_SEEDS}


def bench_wide(args: argparse.Namespace) -> None:
    """Section 7: the wider generator (issue 27), training and validation seeds, dense flow EPE."""
    print("\n## Wider generator (make_wide_pairs: similarity + 8 bumps of N(0, 2.3 / 4.5 / 6.8 % of the size), "
          "no bound on the field's derivative; ratio 0.9 / none / 0.95)\n")
    summary, missed = [], []
    families = [(f, WIDE_FAMILIES[f]) for f in args.wide_families]
    options = (("default", {}), ("dense_detail=True", {"dense_detail": True}))
    for label, extra in options[:1] if args.wide_default_only else options:
        for family, seeds in families:
            rows, means, under3, said = [], [], [], []
            for i, pair in enumerate(make_wide_pairs(seeds, max_side=args.max_side)):
                true = pair.true_flow()
                valid = _valid(pair, true)
                t = time.perf_counter()
                m = match_images(pair.a, pair.b, rng=0, options={"ratio": pair.ratio, **extra})
                s = time.perf_counter() - t
                e = np.linalg.norm(dense_flow(m.transform, pair.a.shape[:2]).astype(np.float64) - true, axis=2)[valid]
                means.append(float(e.mean()))
                under3.append(float(np.mean(e < 3.0)))
                said.append(bool(m.converged))
                dense = (m.confidence_summary or {}).get("dense", "-")
                rows.append([pair.name, f"{pair.strength:.1%}", "none" if pair.ratio == 1.0 else f"{pair.ratio}",
                             f"{pair.min_det:.3f}", m.n_matches, m.n_inliers, m.n_dense, dense, m.converged,
                             means[-1], under3[-1], float(np.max(e)), s])
                print(f"  wide {label} {family} {i} {pair.name}: {means[-1]:.2f} px", file=sys.stderr)
                if not extra and means[-1] > 3.0:
                    missed.append([f"{pair.name} ({family})", f"{pair.strength:.1%}", means[-1],
                                   *_missed_area(pair, true)])
            print(f"### {family} ({len(seeds)} pairs, seeds {seeds[0]}-{seeds[-1]}), {label}\n")
            print(table(["pair", "bump std", "ratio test", "min det", "putatives", "inliers", "n_dense", "dense",
                         "converged", "mean EPE", "points < 3 px", "max EPE", "s"], rows))
            print()
            mm, ok = np.array(means), np.array(said)
            summary.append([family, label, float(mm.mean()), float(np.median(mm)), float(np.mean(under3)),
                            f"{np.mean(mm < 3.0):.0%}", float(mm.max()), rows[int(np.argmax(mm))][0],
                            f"{int(np.sum((mm > 3.0) & ~ok))} / {int(np.sum(mm > 3.0))}",
                            f"{int(np.sum((mm <= 3.0) & ok))} / {int(np.sum(mm <= 3.0))}",
                            float(np.median([r[-1] for r in rows]))])
    print(table(["family", "options", "mean EPE", "median pair EPE", "share of points < 3 px", "pairs < 3 px",
                 "worst pair mean EPE", "worst pair", "over 3 px said converged=False",
                 "within 3 px converged=True", "median s"], summary))
    print("\n(EPE: px over the pixels of a whose true position is inside b; mean EPE: mean over pairs of each pair's "
          "mean; share of points: mean over pairs; match_images(a, b, rng=0, options={'ratio': ..., ...}) + "
          "dense_flow.)")
    print("\n### Pairs over 3 px by default: the sparse fit's missed area\n")
    print(table(["pair", "bump std", "mean EPE", "putatives in the missed area", "correct there", "kept there",
                 "kept and correct"], missed))
    print("\n(missed area: where match_images(..., dense=False) is over 10 px off the true field, at the putatives' "
          "sources in a; correct: within 3 px of the true position in b)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data", help="benchmark data folder (default ../shared/data)")
    sections = ["families", "synthetic", "graf", "labelled", "timing", "flow", "stain", "wide", "he"]
    parser.add_argument("--sections", nargs="+", default=sections, choices=sections)
    parser.add_argument("--pairs", type=int, default=20, help="synthetic pairs (>= 20 for the reported table)")
    parser.add_argument("--max-side", type=int, default=512, help="sample images are resized to this longer side")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=5, help="timing repetitions")
    parser.add_argument("--no-deepflow", action="store_true", help="synthetic section: skip DeepFlow")
    parser.add_argument("--peers", nargs="*", default=list(PEERS), choices=list(PEERS),
                        help="families section: the peers to run (default all)")
    parser.add_argument("--quick", action="store_true",
                        help="families section: 8 + 11 pairs, elastix at most 128 iterations per stage")
    parser.add_argument("--peer-every", type=int, default=6,
                        help="families section: TV-L1 and elastix run on every k-th pair only (default 6; 1 = all)")
    parser.add_argument("--elastix-iter", type=int, default=256,
                        help="families section: elastix iterations per stage at most (default 256 as in its "
                             "default maps; --quick: 128)")
    parser.add_argument("--peer-cache", default=None,
                        help="families section: JSON file of peer results to reuse / extend (same pairs, settings)")
    parser.add_argument("--figures", default=None,
                        help="families section: write images_confidence.png into this folder (e.g. benchmarks/figures)")
    parser.add_argument("--stain-peers", nargs="*", default=list(STAIN_PEERS), choices=list(STAIN_PEERS),
                        help="stain and he sections: the peers to run (default all; none: --stain-peers with no names)")
    parser.add_argument("--wide-families", nargs="+", default=["training", "validation"], choices=list(WIDE_FAMILIES),
                        help="wide section: the seed sets (training 9000-9026 and pool 9300-9380 chosen on; "
                             "validation 9100-9126 and fresh 9200-9253 never tuned on)")
    parser.add_argument("--wide-default-only", action="store_true",
                        help="wide section: the default options only (no dense_detail=True rows)")
    parser.add_argument("--seeds", nargs="*", type=int, default=[],
                        help="families section: also run reglib with these rng seeds (seed stability)")
    args = parser.parse_args(argv)
    print(f"# bench_images  (OpenCV {cv2.__version__}, numpy {np.__version__})")
    for section in args.sections:
        {"families": bench_families, "synthetic": bench_synthetic, "graf": bench_graf, "labelled": bench_labelled,
         "timing": bench_timing, "flow": bench_flow, "stain": bench_stain,
         "wide": bench_wide, "he": bench_he}[section](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
