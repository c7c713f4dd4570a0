"""Benchmark of filter_matches (issue 2): accuracy on labelled pairs and graf, scaling in N.

Run from the project root:  python benchmarks/bench_filter.py [--data ../shared/data] [--quick]
Prints markdown tables. Peers: OpenCV's MAGSAC++ (homography and fundamental matrix).
Timings are medians of repeated calls of the estimator alone, default BLAS threads, and depend on
what else the machine is doing: compare rows measured in the same run.
"""
from __future__ import annotations

import argparse
import time
import tracemalloc
from pathlib import Path

import cv2
import numpy as np

from reglib import filter_matches

OURS = {
    "l2e (default: affine + kernel)": dict(method="l2e"),
    "l2e pure field (published form)": dict(method="l2e", options={"linear": "none"}),
    "l2e homography + kernel": dict(method="l2e", options={"linear": "homography"}),
    "vfc (published defaults)": dict(method="vfc"),
}


def magsac(kind: str):
    def run(src, dst):
        if len(src) < 8:
            return np.zeros(len(src), bool)
        if kind == "homography":
            _, mask = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, 3.0, maxIters=10000, confidence=0.999)
        else:
            _, mask = cv2.findFundamentalMat(src, dst, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)
        return np.zeros(len(src), bool) if mask is None else mask.ravel().astype(bool)
    return run


PEERS = {"OpenCV MAGSAC++ homography": magsac("homography"), "OpenCV MAGSAC++ fundamental": magsac("fundamental")}


def prf(found: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    tp = np.count_nonzero(found & truth)
    p = tp / max(np.count_nonzero(found), 1)
    r = tp / max(np.count_nonzero(truth), 1)
    return p, r, 2 * p * r / max(p + r, 1e-12)


def timed(fn, repeat: int):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times)) * 1e3


def all_methods():
    for name, kw in OURS.items():
        yield name, (lambda s, d, kw=kw: filter_matches(s, d, rng=0, **kw).inliers)
    yield from PEERS.items()


def labelled_pairs(data: Path):
    for name in ("church", "retina", "remote_sensing"):
        z = np.load(data / "image_pairs" / name / "putative_matches.npz")
        truth = np.zeros(len(z["src"]), bool)
        truth[z["correct"]] = True
        yield name, z["src"].astype(np.float64), z["dst"].astype(np.float64), truth


def graf_pairs(data: Path):
    """SIFT (RootSIFT) putative matches of graf 1-k, ratio 0.8, labelled true within 3 px of H1tok."""
    folder = data / "image_pairs" / "graf"
    sift = cv2.SIFT_create(nfeatures=4000)

    def describe(path):
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        kp, desc = sift.detectAndCompute(img, None)
        desc = np.sqrt(desc / (desc.sum(1, keepdims=True) + 1e-12)).astype(np.float32)
        return np.float64([k.pt for k in kp]), desc

    pa, da = describe(folder / "img1.png")
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    for k in (2, 3, 4):
        pb, db = describe(folder / f"img{k}.png")
        knn = matcher.knnMatch(da, db, k=2)
        good = [m for m, n in knn if m.distance < 0.8 * n.distance]
        src = pa[[m.queryIdx for m in good]]
        dst = pb[[m.trainIdx for m in good]]
        h = np.loadtxt(folder / f"H1to{k}p")
        proj = cv2.perspectiveTransform(src[:, None], h)[:, 0]
        truth = np.linalg.norm(proj - dst, axis=1) < 3.0
        yield f"graf 1-{k}", src, dst, truth


def accuracy_table(rows, repeat: int) -> None:
    print("| pair | N | true | method | precision | recall | F1 | ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, src, dst, truth in rows:
        for method, fn in all_methods():
            found, ms = timed(lambda: fn(src, dst), repeat)
            p, r, f = prf(found, truth)
            print(f"| {name} | {len(src)} | {truth.sum()} | {method} | {p:.3f} | {r:.3f} | {f:.3f} | {ms:.1f} |")


def scaling_scene(n: int, outlier_rate: float, seed: int = 0):
    """src uniform in a 1000 px box; dst a similarity of src plus a smooth field plus 1 px noise.

    The field: 40 px amplitude at ~500 px wavelength plus 8 px at ~150 px wavelength (random
    directions and phases). 40 px at a 150 px wavelength, as first specified, would fold the plane
    (strain 2 pi 40 / 150 = 1.7 > 1): no smooth one-to-one map does that, so the short wave is
    given the largest amplitude that keeps the map one-to-one with margin.
    """
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 1000, (n, 2))
    th = np.deg2rad(rng.uniform(-30, 30))
    s = rng.uniform(0.8, 1.25)
    rot = s * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    field = np.zeros_like(src)
    for amp, wavelength in ((40.0, 500.0), (8.0, 150.0)):
        for comp in range(2):
            ang = rng.uniform(0, 2 * np.pi)
            k = 2 * np.pi / wavelength * np.array([np.cos(ang), np.sin(ang)])
            field[:, comp] += amp / np.sqrt(2) * np.sin(src @ k + rng.uniform(0, 2 * np.pi))
    clean = (src - 500) @ rot.T + 500 + field
    dst = clean + rng.normal(0, 1.0, (n, 2))
    bad = rng.random(n) < outlier_rate
    dst[bad] = rng.uniform(0, 1000, (int(bad.sum()), 2))
    return src, dst, ~bad, clean


def scaling_table(sizes, repeat: int) -> None:
    print("| N | outliers | method | F1 | median ms | peak MiB (tracemalloc) | MiB per 1k matches"
          " | field error px (median / p90) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for n in sizes:
        for rate in (0.5, 0.9):
            src, dst, truth, clean = scaling_scene(n, rate)
            fit = filter_matches(src, dst, rng=0)
            # Error of the estimated map against the noise-free one, at the true matches' sources.
            err = np.linalg.norm(fit.transform(src[truth]) - clean[truth], axis=1)
            field = f"{np.median(err):.2f} / {np.percentile(err, 90):.2f}"
            for method, fn in (("l2e", lambda s, d: filter_matches(s, d, rng=0).inliers),
                               ("OpenCV MAGSAC++ homography", PEERS["OpenCV MAGSAC++ homography"])):
                found, ms = timed(lambda: fn(src, dst), repeat)
                tracemalloc.start()
                fn(src, dst)
                peak = tracemalloc.get_traced_memory()[1] / 2**20
                tracemalloc.stop()
                _, _, f = prf(found, truth)
                shown = field if method == "l2e" else "-"
                print(f"| {n} | {int(rate * 100)} % | {method} | {f:.3f} | {ms:.1f} | {peak:.1f} | {peak / n * 1000:.2f}"
                      f" | {shown} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", type=Path, default=Path("../shared/data"))
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="skip N = 100,000")
    args = ap.parse_args()
    print("## Labelled putative matches (precision / recall / F1 of the kept matches)\n")
    accuracy_table(labelled_pairs(args.data), args.repeat)
    print("\n## Oxford graf, SIFT ratio 0.8, truth = within 3 px of the ground-truth homography\n")
    accuracy_table(graf_pairs(args.data), args.repeat)
    print("\n## Scaling (synthetic, 1000 px box; time of the filter call alone)\n")
    scaling_table((1000, 10000) if args.quick else (1000, 10000, 100000), args.repeat)


if __name__ == "__main__":
    main()
