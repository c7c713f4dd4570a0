"""Image pipeline benchmark: reglib.match_images against OpenCV DIS, DeepFlow and MAGSAC++.

Sections (all print markdown tables):

1. synthetic  Non-rigid pairs with exact ground truth from scikit-image's bundled photographs
              (``_synthetic_pairs.py``): inlier precision / recall / F1 on the SIFT putatives (loose
              ratio test 0.9, and none: every nearest neighbour) and flow end-point error over every
              pixel of a whose true position falls inside b.
2. graf       Oxford graffiti 1-2, 1-3, 1-4 (ground-truth homographies; a match is true within 3 px).
3. labelled   church, retina, remote_sensing: the labelled putatives through our estimator, and the
              whole pipeline's transform scored against the labels.
4. timing     End-to-end match_images on two 512x768 (W x H) images against bare OpenCV SIFT
              extraction + brute-force k-NN matching, in one run.
5. flow       dense_flow on a 1-megapixel grid against evaluating the transform at every pixel.

Usage (from the project root)::

    .venv/bin/python benchmarks/bench_images.py                 # all sections, ~3-5 minutes
    .venv/bin/python benchmarks/bench_images.py --sections synthetic --pairs 20
    .venv/bin/python benchmarks/bench_images.py --data ../shared/data --no-deepflow

Data for sections 2-4: ``--data`` (default ``../shared/data``; see its README for the sources).
Not run by CI.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _synthetic_pairs import make_pairs  # noqa: E402

from reglib import dense_flow, filter_matches, match_images  # noqa: E402
from reglib.features.sift import detect_sift, match_descriptors, to_gray_uint8  # noqa: E402
from reglib.io import read_image  # noqa: E402


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
                inl_rows.setdefault((f"reglib {method.upper()}", ratio), []).append((*prf(m.inliers, truth), truth.mean(), m.n_matches, ms))
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

    def ours(dense: bool):
        return lambda: match_images(a, b, rng=0, options={"dense": dense})

    runs = {"bare OpenCV SIFT + BF k-NN + ratio": bare, "match_images, dense off": ours(False),
            "match_images, dense on": ours(True)}
    times: dict[str, list[float]] = {k: [] for k in runs}
    for _ in range(args.repeat):
        for name, fn in runs.items():  # interleaved, so machine load hits all alike
            t = time.perf_counter()
            fn()
            times[name].append((time.perf_counter() - t) * 1000)
    base = float(np.median(times["bare OpenCV SIFT + BF k-NN + ratio"]))
    m = match_images(a, b, rng=0)
    print(f"\n## End-to-end time on {label}, median of {args.repeat} (load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores)\n")
    rows = [[name, float(np.median(v)), float(np.median(v)) / base] for name, v in times.items()]
    print(table(["run", "median ms", "x bare SIFT"], rows))
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data", help="benchmark data folder (default ../shared/data)")
    parser.add_argument("--sections", nargs="+", default=["synthetic", "graf", "labelled", "timing", "flow"],
                        choices=["synthetic", "graf", "labelled", "timing", "flow"])
    parser.add_argument("--pairs", type=int, default=20, help="synthetic pairs (>= 20 for the reported table)")
    parser.add_argument("--max-side", type=int, default=512, help="sample images are resized to this longer side")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=5, help="timing repetitions")
    parser.add_argument("--no-deepflow", action="store_true", help="skip DeepFlow (the slowest peer)")
    args = parser.parse_args(argv)
    print(f"# bench_images  (OpenCV {cv2.__version__}, numpy {np.__version__})")
    for section in args.sections:
        {"synthetic": bench_synthetic, "graf": bench_graf, "labelled": bench_labelled,
         "timing": bench_timing, "flow": bench_flow}[section](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
