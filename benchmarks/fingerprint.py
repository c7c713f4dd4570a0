"""Fingerprint of the library's numerical answers on generated inputs, to compare two commits.

A refactoring that promises "numerically unchanged" runs this before and after and compares:

    python benchmarks/fingerprint.py --out /tmp/before.json          # on the old commit
    python benchmarks/fingerprint.py --compare /tmp/before.json      # on the new one

Every inlier mask is hashed exactly; transforms are evaluated on fixed points and compared to
``--tol`` (default 1e-9 px). No data from ``../shared`` is needed: the inputs are made here
(synthetic matches, scikit-image's bundled photographs, the bundled example pair).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

import reglib


def _mask(m: np.ndarray) -> str:
    return hashlib.sha1(np.packbits(np.asarray(m, bool)).tobytes() + str(len(m)).encode()).hexdigest()[:16]


def _vals(x: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(x, float).ravel()]


def _matches(n: int, d: int, outliers: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 500, (n, d))
    dst = src * 1.05 + 8 + 6 * np.sin(src / 90.0) + rng.normal(0, 0.5, (n, d))
    bad = rng.random(n) < outliers
    dst[bad] = rng.uniform(0, 500, (int(bad.sum()), d))
    return src, dst


def _filter_cases() -> dict[str, dict]:
    out = {}
    probe2 = np.mgrid[0:500:50, 0:500:50].reshape(2, -1).T.astype(float)
    probe3 = np.random.default_rng(9).uniform(0, 500, (50, 3))
    for d, probe in ((2, probe2), (3, probe3)):
        for method in ("l2e", "vfc"):
            for n, share in ((300, 0.5), (1500, 0.7)):
                src, dst = _matches(n, d, share, n + d)
                r = reglib.filter_matches(src, dst, method=method, rng=1)
                out[f"filter/{method}/{d}d/{n}/{share}"] = {
                    "inliers": _mask(r.inliers), "n_inliers": int(r.n_inliers), "converged": bool(r.converged),
                    "reason": r.reason, "at": _vals(r.transform(probe))}
    return out


def _image_cases() -> dict[str, dict]:
    import cv2
    from skimage import data

    out = {}
    root = Path(reglib.__file__).parent / "examples"
    probe = np.mgrid[0:300:37, 0:300:41].reshape(2, -1).T.astype(float)

    def record(key: str, m: reglib.ImageMatch) -> None:
        out[key] = {"inliers": _mask(m.inliers), "n": int(len(m.inliers)), "n_inliers": int(m.inliers.sum()),
                    "n_dense": int(m.n_dense), "converged": bool(m.converged), "reason": m.reason,
                    "features": m.features, "at": _vals(m.transform(probe)),
                    "confidence": m.to_dict().get("confidence"), "fold": float(m.fold_fraction)}

    a, b = root / "cat_a.jpg", root / "cat_b.jpg"
    for method in ("l2e", "vfc"):
        record(f"match/cat/{method}", reglib.match_images(a, b, method=method, rng=0))
    record("match/cat/nodense", reglib.match_images(a, b, rng=0, options={"dense": False}))
    cam = data.camera()
    h, w = cam.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    mx = xx + 6 * np.sin(yy / 70) + 4
    my = yy + 5 * np.cos(xx / 60) - 3
    warped = cv2.remap(cam, mx, my, cv2.INTER_LINEAR)
    record("match/camera/sift", reglib.match_images(cam, warped, rng=3))
    inverted = (255 - cv2.GaussianBlur(warped, (0, 0), 1.5)).astype(np.uint8)
    record("match/camera/multimodal", reglib.match_images(cam, inverted, features="multimodal", rng=3))
    record("match/camera/auto", reglib.match_images(cam, inverted, features="auto", rng=3))
    edges_a = (cv2.Canny(cam, 80, 160) > 0).astype(np.uint8) * 255
    edges_b = (cv2.Canny(warped, 80, 160) > 0).astype(np.uint8) * 255
    record("match/camera/shape_context", reglib.match_images(edges_a, edges_b, features="shape_context", rng=3,
                                                             options={"contour_points": 150}))
    m = reglib.match_images(cam, warped, rng=3)
    flow = reglib.dense_flow(m.transform, cam.shape)
    out["flow/camera"] = {"sum": float(np.abs(flow).sum()), "at": _vals(flow[::97, ::89])}
    out["warp/camera"] = {"sum": float(reglib.warp_image(warped, m.transform, cam.shape)[0].astype(float).sum())}
    return out


def _registration_cases() -> dict[str, dict]:
    out = {}
    rng = np.random.default_rng(5)
    t = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    shape2 = np.c_[np.cos(t) * (1 + 0.3 * np.cos(3 * t)), np.sin(t) * (1 + 0.2 * np.sin(2 * t))]
    target2 = shape2 * 1.1 + 0.05 * np.sin(shape2[:, ::-1] * 2) + 0.2 + rng.normal(0, 0.005, shape2.shape)
    u = rng.normal(size=(400, 3))
    sphere = u / np.linalg.norm(u, axis=1, keepdims=True) * np.array([1.0, 0.7, 0.5])
    sphere[:, 2] += 0.2 * sphere[:, 0] ** 2
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    target3 = sphere @ rot.T + [0.1, -0.2, 0.05] + rng.normal(0, 0.002, sphere.shape)
    colors = np.clip(0.5 + 0.5 * sphere, 0, 1)
    for method in ("l2e", "cpd", "cpd-rigid", "cpd-affine"):
        r = reglib.register_points(shape2, target2, method=method, rng=0)
        out[f"register/{method}/2d"] = {"at": _vals(r.registered), "converged": bool(r.converged),
                                        "n_iter": int(r.n_iter)}
    for method in ("icp", "color-gmm", "density-adaptive", "bayes", "cpd-rigid"):
        extra = {"model_colors": colors, "target_colors": colors} if method == "color-gmm" else {}
        r = reglib.register_points(sphere, target3, method=method, rng=0, **extra)
        out[f"register/{method}/3d"] = {"at": _vals(r.registered[::7]), "converged": bool(r.converged),
                                        "n_iter": int(r.n_iter)}
    # an organized scan for icp-hmrf: a wavy surface seen on a 40 x 50 grid
    yy, xx = np.mgrid[0:40, 0:50] / 40.0
    scan = np.dstack([xx, yy, 0.1 * np.sin(3 * xx) * np.cos(2 * yy) + 1.0])
    moved = scan.reshape(-1, 3) @ rot.T * 1.0 + [0.02, -0.01, 0.01]
    r = reglib.register_points(scan, moved, method="icp-hmrf", rng=0)
    out["register/icp-hmrf/3d"] = {"at": _vals(r.registered[::11]), "converged": bool(r.converged),
                                   "n_iter": int(r.n_iter)}
    return out


def _compare(a: object, b: object, tol: float, path: str, diffs: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                diffs.append(f"{path}/{k}: only in {'before' if k in a else 'after'}")
            else:
                _compare(a[k], b[k], tol, f"{path}/{k}", diffs)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            diffs.append(f"{path}: length {len(a)} -> {len(b)}")
            return
        worst = max((abs(x - y) for x, y in zip(a, b, strict=True) if isinstance(x, float)), default=0.0)
        if worst > tol:
            diffs.append(f"{path}: max difference {worst:.3g}")
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            if not isinstance(x, float):
                _compare(x, y, tol, f"{path}[{i}]", diffs)
    elif isinstance(a, float) and isinstance(b, float):
        if abs(a - b) > tol * max(1.0, abs(a)):
            diffs.append(f"{path}: {a!r} -> {b!r}")
    elif a != b:
        diffs.append(f"{path}: {a!r} -> {b!r}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="write the fingerprint here (JSON)")
    parser.add_argument("--compare", help="compare with this earlier fingerprint; exit 1 on a difference")
    parser.add_argument("--tol", type=float, default=1e-9)
    parser.add_argument("--only", choices=("filter", "image", "registration"), action="append")
    args = parser.parse_args()
    parts = {"filter": _filter_cases, "image": _image_cases, "registration": _registration_cases}
    result: dict[str, dict] = {}
    for name, fn in parts.items():
        if not args.only or name in args.only:
            result.update(fn())
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1))
    if args.compare:
        before = json.loads(Path(args.compare).read_text())
        before = {k: v for k, v in before.items() if k in result}
        diffs: list[str] = []
        _compare(before, json.loads(json.dumps(result)), args.tol, "", diffs)
        for d in diffs:
            print(d)
        print(f"{len(result)} cases, {len(diffs)} differences")
        return 1 if diffs else 0
    print(f"{len(result)} cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
