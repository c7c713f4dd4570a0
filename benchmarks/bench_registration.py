"""Point-set registration benchmark: reglib.register_points against pycpd on public data.

Data (not shipped; see ``--data``, default ``../shared/data``):
- ``chui_rangarajan/``: the Chui-Rangarajan fish and Chinese-character series (deformation, noise,
  outlier, occlusion, rotation), from github.com/jiayi-ma/PR-GLS. Metric: mean distance between
  the registered model and the truth (occlusion: from each target point to the nearest registered
  model point), averaged over trials 1, 11, ..., 91 of every level and over both shapes.
- ``pointsets3d/``: the face pair (23,728 index-aligned points) and the bunny pair (8,171 points)
  from github.com/ohirose/bcpd-dataset. The target is rotated by a random rotation first.

Usage::

    python benchmarks/bench_registration.py [--data ../shared/data] [--step 10] [--skip-3d] [--figure PATH]
        [--methods cpd-net,cpd (pycpd)]

Prints the tables and writes ``benchmarks/figures/registration.png`` (before / after of a fish and
a face) unless ``--figure ''``.
"""
from __future__ import annotations

import argparse
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from reglib import register_points

try:  # optional peer
    from pycpd import DeformableRegistration
except ImportError:  # pragma: no cover
    DeformableRegistration = None

SERIES = ("def", "noise", "outlier", "occlusion", "rot")
ANCHORS = {"def": "0.049 / 0.017", "noise": "0.053 / 0.031", "outlier": "0.070 / ~0.10",
           "occlusion": "0.036 / none", "rot": "0.256 / 0.272"}


def _methods():
    out = {
        "l2e": lambda m, t: register_points(m, t, rng=0).transform(m),
        "l2e (rotation off)": lambda m, t: register_points(m, t, options={"rotation": False}, rng=0).transform(m),
        "cpd (reglib)": lambda m, t: register_points(m, t, method="cpd", rng=0).transform(m),
        "cpd-net": lambda m, t: register_points(m, t, method="cpd-net", rng=0).registered,
        "cpd-net + refine": lambda m, t: register_points(m, t, method="cpd-net", options={"refine": 20},
                                                         rng=0).registered,
    }
    if DeformableRegistration is not None:
        out["cpd (pycpd)"] = lambda m, t: DeformableRegistration(X=t, Y=m).register()[0]
    return out


def _error(series, out, target, truth):
    if series == "occlusion":
        return float(cKDTree(out).query(target)[0].mean())
    return float(np.linalg.norm(out - truth, axis=1).mean())


def bench_chui(root: Path, step: int, only: tuple[str, ...] = ()) -> dict:
    methods = {k: v for k, v in _methods().items() if not only or k in only}
    per_level: dict = {}
    summary: dict = {}
    times: dict = {name: [] for name in methods}
    for series in SERIES:
        for name, fn in methods.items():
            level_means = []
            for shape in ("fish", "chinese"):
                data = np.load(root / "chui_rangarajan" / f"{shape}_{series}.npz")
                levels = sorted({int(k.split("_")[0][5:]) for k in data.files})
                for level in levels:
                    models, targets = data[f"level{level}_model"], data[f"level{level}_target"]
                    truths = data.get(f"level{level}_truth")
                    errs = []
                    for trial in range(0, len(models), step):
                        t0 = time.perf_counter()
                        out = fn(models[trial], targets[trial])
                        if shape == "fish":
                            times[name].append(time.perf_counter() - t0)
                        errs.append(_error(series, out, targets[trial], None if truths is None else truths[trial]))
                    per_level[(series, name, shape, level)] = float(np.mean(errs))
                    level_means.append(float(np.mean(errs)))
            summary[(series, name)] = float(np.mean(level_means))
    return {"methods": list(methods), "summary": summary, "per_level": per_level,
            "ms": {k: 1000 * float(np.median(v)) for k, v in times.items()}}


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _timed(fn):
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn()
    elapsed = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return out, elapsed, peak / 2**20


def bench_3d(root: Path) -> list:
    rng = np.random.default_rng(0)
    face_x = np.loadtxt(root / "pointsets3d" / "face_x.txt")
    face_y = np.loadtxt(root / "pointsets3d" / "face_y.txt")
    bunny_x = np.loadtxt(root / "pointsets3d" / "bunny_x.txt")
    bunny_y = np.loadtxt(root / "pointsets3d" / "bunny_y.txt")
    rot = _random_rotation(rng)
    sub = np.sort(rng.choice(len(face_x), 10000, replace=False))
    cases = [("face 23,728", face_x, face_y), ("face 10k", face_x[sub], face_y[sub]), ("bunny 8,171", bunny_x, bunny_y)]
    rows = []
    for label, model, target in cases:
        centre = target.mean(0)
        rotated = (target - centre) @ rot.T + centre
        scale = float(np.sqrt(((target - centre) ** 2).sum(1).mean()))
        for name, kw in (("l2e", {}), ("cpd low-rank (reglib, 1000-pt samples)",
                                        {"method": "cpd", "options": {"low_rank": True, "max_iter": 60}})):
            res, sec, mib = _timed(
                lambda model=model, rotated=rotated, kw=kw: register_points(model, rotated, rng=0, **kw))
            out = res.transform(model)
            if label.startswith("face"):
                err = float(np.linalg.norm(out - rotated, axis=1).mean())
                metric = "mean error vs truth"
            else:
                err = float(cKDTree(rotated).query(out)[0].mean())
                metric = "mean distance to nearest target"
            rows.append((label, name, err, err / scale, sec, mib, metric))
            print(f"  {label:12s} {name:30s} {metric} {err:.4g} ({err / scale:.4f} of RMS radius) "
                  f"{sec:.2f} s, peak {mib:.0f} MiB", flush=True)
    return rows


def draw_figure(root: Path, path: Path) -> None:
    import cv2

    d = np.load(root / "chui_rangarajan" / "fish_def.npz")
    fish_m, fish_t = d["level3_model"][0], d["level3_target"][0]
    a = np.deg2rad(120)
    fish_t = fish_t @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T
    fish_r = register_points(fish_m, fish_t, rng=0).transform(fish_m)
    face_x = np.loadtxt(root / "pointsets3d" / "face_x.txt")
    face_y = np.loadtxt(root / "pointsets3d" / "face_y.txt")
    rng = np.random.default_rng(0)
    sub = np.sort(rng.choice(len(face_x), 10000, replace=False))
    fx, fy = face_x[sub], face_y[sub]
    c = fy.mean(0)
    fy = (fy - c) @ _random_rotation(rng).T + c
    fr = register_points(fx, fy, rng=0).transform(fx)

    size = 360
    panels = []

    def panel(sets, title, proj=None):
        img = np.full((size, size, 3), 255, np.uint8)
        pts = [s if proj is None else s[:, proj] for s, _ in sets]
        allp = np.vstack(pts)
        lo, hi = allp.min(0), allp.max(0)
        sc = (size - 40) / max(hi - lo)
        for (p, (_, col)) in zip(pts, sets, strict=True):
            q = ((p - lo) * sc + 20).astype(int)
            q[:, 1] = size - q[:, 1]  # y up
            for x, y in q[:: max(1, len(q) // 3000)]:
                cv2.circle(img, (int(x), int(y)), 2, col, -1, lineType=cv2.LINE_AA)
        cv2.putText(img, title, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        return img

    red, blue = (40, 40, 220), (200, 90, 20)  # BGR: model red, target blue
    panels.append(panel([(fish_t, blue), (fish_m, red)], "fish: model (red), target (blue)"))
    panels.append(panel([(fish_t, blue), (fish_r, red)], "fish: after l2e"))
    panels.append(panel([(fy, blue), (fx, red)], "face 10k: before (x-y view)", proj=[0, 1]))
    panels.append(panel([(fy, blue), (fr, red)], "face 10k: after l2e", proj=[0, 1]))
    img = np.vstack([np.hstack(panels[:2]), np.hstack(panels[2:])])
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)
    print(f"figure -> {path}")


def settled_verdict(data: Path, step: int) -> None:
    """Whether a registration that stopped at its cap is worse than one that settled (the ``not_settled`` reason):
    the share of answers within 2 % of the target's extent (the error of :func:`_error`), for the iterative
    non-rigid methods over every series, level and ``step``-th trial of both Chui-Rangarajan shapes."""
    print("| method | settled | of those within 2 % | stopped by the cap | of those within 2 % | worst settled |")
    print("| --- | --- | --- | --- | --- | --- |")
    for method in ("l2e", "cpd", "cpd-affine"):
        rows = []
        for series in SERIES:
            for shape in ("fish", "chinese"):
                z = np.load(data / "chui_rangarajan" / f"{shape}_{series}.npz")
                for level in sorted({int(k.split("_")[0][5:]) for k in z.files}):
                    models, targets = z[f"level{level}_model"], z[f"level{level}_target"]
                    truths = z.get(f"level{level}_truth")
                    for trial in range(0, len(models), step):
                        reg = register_points(models[trial], targets[trial], method=method, rng=0)
                        truth = None if truths is None else truths[trial]
                        err = _error(series, reg.registered, targets[trial], truth)
                        rows.append((err / np.ptp(targets[trial], axis=0).max(), reg.converged))
        settled = [e for e, c in rows if c]
        capped = [e for e, c in rows if not c]
        share = [f"{np.mean(np.array(x) <= 0.02):.0%}" if x else "-" for x in (settled, capped)]
        worst = f"{max(settled):.3f}" if settled else "-"
        print(f"| {method} | {len(settled)} | {share[0]} | {len(capped)} | {share[1]} | {worst} |")


def cpd_net_verdict(data: Path) -> None:
    """CPD-Net's ``converged`` against its error to the truth (mean, over the target's extent; 2 % the line) on
    the deformation series, every trial: levels 2-5 chose the threshold, level 1 and the examples did not."""
    import reglib

    def error(reg: reglib.Registration, truth: np.ndarray) -> float:
        return float(np.linalg.norm(reg.registered - truth, axis=1).mean() / np.ptp(truth, axis=0).max())

    print("| set | trials | within 2 % | of those converged | over 2 % | of those converged | worst error converged |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for shape in ("fish", "chinese"):
        z = np.load(data / "chui_rangarajan" / f"{shape}_def.npz")
        for level in range(1, 6):
            models, targets, truths = (z[f"level{level}_{k}"] for k in ("model", "target", "truth"))
            rows = []
            for a, b, truth in zip(models, targets, truths, strict=True):
                reg = reglib.register_points(a, b, method="cpd-net", rng=0)
                rows.append((error(reg, truth), reg.converged))
            good = [c for e, c in rows if e <= 0.02]
            bad = [c for e, c in rows if e > 0.02]
            worst = max((e for e, c in rows if c), default=float("nan"))
            print(f"| {shape} def level {level} | {len(rows)} | {len(good)} | {sum(good)} | {len(bad)} | {sum(bad)} | "
                  f"{worst:.4f} |")
    model = np.random.default_rng(0).uniform(-1, 1, (200, 2))
    target = model @ [[0.9, -0.3], [0.3, 0.9]] + 0.1
    fish_a = np.loadtxt(data / "cpd_fish" / "fish_source.txt")
    fish_b = np.loadtxt(data / "cpd_fish" / "fish_target.txt")
    for name, a, b in (("README example", model, target), ("CPD fish pair", fish_a, fish_b)):
        reg = reglib.register_points(a, b, method="cpd-net", rng=0)
        print(f"| {name} | 1 | error {error(reg, b):.4f} | converged {reg.converged} ({reg.reason}) | | | |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data"))
    ap.add_argument("--step", type=int, default=10, help="use trials 1, 1+step, ... of every level")
    ap.add_argument("--skip-3d", action="store_true")
    ap.add_argument("--skip-2d", action="store_true")
    ap.add_argument("--figure", default="benchmarks/figures/registration.png")
    ap.add_argument("--methods", default="", help="comma-separated rows of the 2-D table to run (default: all)")
    ap.add_argument("--settled-verdict", action="store_true",
                    help="answers within 2 %% of the extent, settled against stopped by the cap (--step trials)")
    ap.add_argument("--cpd-net-verdict", action="store_true",
                    help="only: CPD-Net's converged against its error on the deformation series and the examples")
    args = ap.parse_args()
    if args.settled_verdict:
        settled_verdict(args.data, args.step)
        return
    if args.cpd_net_verdict:
        cpd_net_verdict(args.data)
        return
    if not args.skip_2d:
        res = bench_chui(args.data, args.step, tuple(n.strip() for n in args.methods.split(",") if n.strip()))
        names = res["methods"]
        print("\nChui-Rangarajan: mean registration error (levels and both shapes averaged)\n")
        print("| series | " + " | ".join(names) + " | anchors CPD (pycpd) / RPM-L2E |")
        print("| --- |" + " --- |" * (len(names) + 1))
        for s in SERIES:
            print(f"| {s} | " + " | ".join(f"{res['summary'][(s, n)]:.3f}" for n in names) + f" | {ANCHORS[s]} |")
        print("| median ms per fish | " + " | ".join(f"{res['ms'][n]:.1f}" for n in names) + " | |")
        print("\nrotation series per level (fish / chinese), degrees 0 30 60 90 120 180\n")
        for n in names:
            for shape in ("fish", "chinese"):
                vals = [res["per_level"][("rot", n, shape, lv)] for lv in range(1, 7)]
                print(f"  {n:22s} {shape:8s} " + " ".join(f"{v:.3f}" for v in vals))
    if not args.skip_3d:
        print("\n3-D (target rotated by a random rotation)\n")
        bench_3d(args.data)
    if args.figure:
        draw_figure(args.data, Path(args.figure))


if __name__ == "__main__":
    main()
