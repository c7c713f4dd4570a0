"""Probabilistic rigid registration benchmark: color-gmm, density-adaptive and bayes against peers.

The three claims of issue 15, each measured with ground truth made from known motions of real
scans (fixed seeds):

1. colour (``color-gmm``, Danelljan et al. 2016): planar patches of the Kinect / stereo frames in
   ``pointsets3d/scans`` (the dominant plane of a floor / table / door window, found by RANSAC).
   The model is one image window of the plane, the target an overlapping window shifted by 10 %
   or 25 % of its width (the in-plane offset the centroid start leaves), moved by a random rigid
   motion (5-30 degrees, translation 10 % of the extent) with 1 mm noise and colour noise 0.02.
   Two planar patches of the same shape fit each other in any in-plane position: geometry alone
   is ambiguous, colour is not. ``milk_color``
   (an object, not planar) is the control, cropped for about 70 % overlap (the offset does not
   apply to it).
2. density (``density-adaptive``, Lawin et al. 2018): the BCPD bunny and the office1 frame, evened
   out on a voxel grid first; the target keeps a uniform density, the model is cropped (about
   80 % overlap) and sampled ``ratio`` times denser on one side of a random plane than on the
   other (ratio 1: control; 10: the claim); motion 10-45 degrees, noise 0.5 % of the extent.
3. outliers (``bayes``, Zhou et al. 2019): the bunny (voxel-grid 2000 points), motion 10-45
   degrees, noise 0.5 %, and 0-50 % of the target points uniform outliers in the bounding box
   enlarged by 20 % (fraction = outliers / all target points).

Peers in the same run: reglib's ``cpd-rigid`` (``register_points(method="cpd-rigid",
options={"scale": False})``, and with its outlier weight w = 0.5 in the outlier study), Open3D
0.20 point-to-point ICP and (colour study) multi-scale colored ICP. Every method starts from the
same place: the model's centroid moved onto the target's (our methods normalize that way; ICP is
given that translation as its initial transform).

Success: rotation error < 2 degrees and mean point error (over the model points, estimated
motion against the true one) < 1 % of the target's bounding-box diagonal.

The start of the three methods (``init``, issue 28): ``--init centroid,features`` runs each of
them once per start given (``centroid``: the centroids aligned, their default and the start of the
peers; ``given``: the caller's pose, here the moved model as it is; ``search`` / ``features``: the
rotation search / the FPFH feature start of ``icp``) and prints, after the studies' tables, one
table of success per case and start with the cells where a start does worse than the first one.
``--no-peers`` leaves out ``cpd-rigid`` and Open3D.

Usage::

    python benchmarks/bench_rigid_probabilistic.py [--data ../shared/data] [--quick] [--trials N]
        [--init centroid,features] [--no-peers]

Prints markdown tables; writes ``benchmarks/figures/prob_color_gmm.png``,
``prob_density_adaptive.png`` and ``prob_bayes.png`` (``--no-figures`` to skip).
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

import reglib
from reglib.registration._mixture import subsample_indices

try:  # optional peer
    import open3d as o3d
except ImportError:  # pragma: no cover
    o3d = None

FIGURES = Path(__file__).resolve().parent / "figures"
# (file, image rows, image columns) of a planar, textured window of each organized frame
PLANES = {
    "kinect_142255.814212": (slice(330, 480), slice(0, 610)),
    "kinect_142256.068683": (slice(330, 480), slice(0, 610)),
    "kinect_142256.332395": (slice(330, 480), slice(0, 610)),
    "office1": (slice(60, 340), slice(250, 460)),
    "table_scene_mug_stereo_textured": (slice(290, 480), slice(150, 640)),
}
Method = Callable[..., np.ndarray]  # (model, target, model_rgb, target_rgb) -> (D, D + 1)


# ---------------------------------------------------------------------------------------------
# ground truth

def _rotation(rng: np.random.Generator, low: float, high: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = np.deg2rad(rng.uniform(low, high))
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def _extent(points: np.ndarray) -> float:
    return float(np.linalg.norm(points.max(0) - points.min(0)))


def _errors(est: np.ndarray, rot: np.ndarray, trans: np.ndarray, model: np.ndarray) -> tuple[float, float]:
    """Rotation error (degrees) and mean point error (units) of ``est`` against the truth.

    The rotation is the nearest one to ``est``'s linear part (its polar factor), so that a map
    that also scales is measured by its rotation; the point error sees the scale.
    """
    u, _, vt = np.linalg.svd(est[:, :3])
    r = (u @ vt) @ rot.T
    ang = float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))
    moved = model @ est[:, :3].T + est[:, 3]
    truth = model @ rot.T + trans
    return ang, float(np.linalg.norm(moved - truth, axis=1).mean())


def _plane_inliers(points: np.ndarray, rng: np.random.Generator, tol: float) -> np.ndarray:
    """Mask of the dominant plane's points (RANSAC on 300 triples, then least squares)."""
    best, best_count = None, -1
    for _ in range(300):
        p = points[rng.choice(len(points), 3, replace=False)]
        nrm = np.cross(p[1] - p[0], p[2] - p[0])
        if np.linalg.norm(nrm) < 1e-12:
            continue
        nrm /= np.linalg.norm(nrm)
        count = int((np.abs((points - p[0]) @ nrm) < tol).sum())
        if count > best_count:
            best, best_count = (p[0], nrm), count
    assert best is not None
    mask = np.abs((points - best[0]) @ best[1]) < tol
    c = points[mask].mean(0)
    nrm = np.linalg.svd(points[mask] - c, full_matrices=False)[2][-1]
    return np.abs((points - c) @ nrm) < tol


# ---------------------------------------------------------------------------------------------
# methods: each returns the (3, 4) [R | t] it found

def _centroid_init(model: np.ndarray, target: np.ndarray) -> np.ndarray:
    init = np.eye(4)
    init[:3, 3] = target.mean(0) - model.mean(0)
    return init


def _o3d_cloud(points: np.ndarray, rgb: np.ndarray | None = None):
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if rgb is not None:
        pc.colors = o3d.utility.Vector3dVector(rgb)
    return pc


def _o3d_icp(model, target, *_):
    ext = _extent(target)
    res = o3d.pipelines.registration.registration_icp(
        _o3d_cloud(model), _o3d_cloud(target), 0.05 * ext, _centroid_init(model, target),
        o3d.pipelines.registration.TransformationEstimationPointToPoint(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=100))
    return np.asarray(res.transformation)[:3]


def _o3d_colored_icp(model, target, model_rgb, target_rgb):
    """Open3D's multi-scale colored ICP (Park et al. 2017), as in its tutorial: 3 voxel scales."""
    ext = _extent(target)
    src, dst = _o3d_cloud(model, model_rgb), _o3d_cloud(target, target_rgb)
    current = _centroid_init(model, target)
    for voxel, iters in ((0.02 * ext, 50), (0.01 * ext, 30), (0.005 * ext, 14)):
        s, d = src.voxel_down_sample(voxel), dst.voxel_down_sample(voxel)
        for pc in (s, d):
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        try:
            res = o3d.pipelines.registration.registration_colored_icp(
                s, d, 1.5 * voxel, current,
                o3d.pipelines.registration.TransformationEstimationForColoredICP(),
                o3d.pipelines.registration.ICPConvergenceCriteria(relative_fitness=1e-6,
                                                                  relative_rmse=1e-6, max_iteration=iters))
            current = np.asarray(res.transformation)
        except RuntimeError:  # no correspondences at this scale: keep the estimate
            pass
    return current[:3]


def _matrix(reg: reglib.Registration) -> np.ndarray:
    """The (3, 4) [A | b] of a registration's affine transform, read off by evaluating it."""
    base = reg.transform(np.zeros((1, 3)))[0]
    return np.c_[(reg.transform(np.eye(3)) - base).T, base]


def _cpd_rigid(w: float = 0.0) -> Method:
    def run(model, target, *_):
        return _matrix(reglib.register_points(model, target, method="cpd-rigid",
                                              options={"scale": False, "outlier_weight": w}, rng=0))
    return run


def _ours(name: str, init: str | None = None) -> Method:
    """One of this benchmark's methods through ``reglib.register_points``: its defaults, and ``init``
    when given."""
    options = None if init is None else {"init": init}

    def run(model, target, model_rgb=None, target_rgb=None):
        colours = {"model_colors": model_rgb, "target_colors": target_rgb} if name == "color-gmm" else {}
        return _matrix(reglib.register_points(model, target, method=name, options=options, rng=0, **colours))
    return run


def _label(name: str, init: str | None) -> str:
    return name if init is None else f"{name} init={init}"


def _ours_all(names: tuple[str, ...], inits: list[str | None]) -> dict[str, Method]:
    """Each of ``names`` once per start of ``inits`` (None: the method's default)."""
    return {_label(name, init): _ours(name, init) for name in names for init in inits}


def _geometry_methods(inits: list[str | None], outliers: bool = False, peers: bool = True) -> dict[str, Method]:
    out = _ours_all(("density-adaptive", "bayes"), inits)
    if not peers:
        return out
    out["cpd-rigid"] = _cpd_rigid()
    if outliers:
        out["cpd-rigid (w=0.5)"] = _cpd_rigid(0.5)
    if o3d is not None:
        out["open3d icp p2p"] = _o3d_icp
    return out


def _init_table(cells: dict[str, dict[str, dict]], inits: list[str | None]) -> None:
    """Success per case and start, for each of our methods; a start worse than the first in a cell is marked."""
    names = ("color-gmm", "density-adaptive", "bayes")
    cols = [(n, i) for n in names for i in inits if any(_label(n, i) in row for row in cells.values())]
    print(f"\n### Starts compared (`init`; the first, {inits[0] or 'default'}, is the reference)\n")
    print("| case | " + " | ".join(_label(n, i) for n, i in cols) + " |")
    print("|" + " --- |" * (len(cols) + 1))
    total = {c: [0, 0] for c in cols}
    drops = {c: 0 for c in cols}
    for case, row in cells.items():
        out = []
        for n, i in cols:
            r = row.get(_label(n, i))
            if r is None:
                out.append("-")
                continue
            ok, k = sum(r["ok"]), len(r["ok"])
            total[(n, i)][0] += ok
            total[(n, i)][1] += k
            ref = row[_label(n, inits[0])]
            worse = ok < sum(ref["ok"])
            drops[(n, i)] += worse
            out.append(f"{ok}/{k}" + (" (drop)" if worse else ""))
        print(f"| {case} | " + " | ".join(out) + " |")
    print("| **all** | " + " | ".join(f"**{total[c][0]}/{total[c][1]}**" for c in cols) + " |")
    print("| cells worse than the first start | " + " | ".join(str(drops[c]) for c in cols) + " |")
    print("| median time (s) | " + " | ".join(
        f"{np.median([t for row in cells.values() if _label(*c) in row for t in row[_label(*c)]['time']]):.2f}"
        for c in cols) + " |")


# ---------------------------------------------------------------------------------------------
# the studies

def _run(methods: dict[str, Method], cases: list[dict]) -> dict[str, dict]:
    """Run every method on every case; per method lists of (rot err, point err / extent, seconds)."""
    out: dict[str, dict] = {name: {"rot": [], "pt": [], "time": [], "ok": []} for name in methods}
    for case in cases:
        for name, fn in methods.items():
            t0 = time.perf_counter()
            est = fn(case["model"], case["target"], case.get("model_rgb"), case.get("target_rgb"))
            dt = time.perf_counter() - t0
            ang, pt = _errors(est, case["rot"], case["trans"], case["model"])
            rel = pt / case["extent"]
            out[name]["rot"].append(ang)
            out[name]["pt"].append(rel)
            out[name]["time"].append(dt)
            out[name]["ok"].append(ang < 2.0 and rel < 0.01)
    return out


def _table(title: str, rows: list[tuple[str, str, dict]]) -> None:
    print(f"\n### {title}\n")
    print("| case | method | success | median rot err (deg) | median point err (% extent) | median time (s) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for case, name, r in rows:
        n = len(r["ok"])
        print(f"| {case} | {name} | {sum(r['ok'])}/{n} | {np.median(r['rot']):.2f} | "
              f"{100 * np.median(r['pt']):.2f} | {np.median(r['time']):.2f} |")


def colour_cases(root: Path, trials: int, rng: np.random.Generator, shift_share: float,
                 with_object: bool) -> dict[str, list[dict]]:
    cases: dict[str, list[dict]] = {}
    scans = root / "pointsets3d" / "scans"
    for name, (rows, cols) in PLANES.items():
        z = np.load(scans / f"{name}.npz")
        xyz = z["xyz"][rows, cols].astype(np.float64)
        rgb = z["rgb"][rows, cols].astype(np.float64) / 255.0
        col_idx = np.broadcast_to(np.arange(xyz.shape[1]), xyz.shape[:2])
        ok = np.isfinite(xyz).all(-1)
        pts, colours, cidx = xyz[ok], rgb[ok], col_idx[ok]
        plane = _plane_inliers(pts, rng, 0.01)
        pts, colours, cidx = pts[plane], colours[plane], cidx[plane]
        width = xyz.shape[1]
        shift = round(shift_share * width)
        a = cidx < width - shift
        b = cidx >= shift
        cases[name] = [_coloured_case(pts, colours, a, b, rng) for _ in range(trials)]
    if not with_object:
        return cases
    z = np.load(scans / "milk_color.npz")
    pts, colours = z["xyz"].astype(np.float64), z["rgb"].astype(np.float64) / 255.0
    cases["milk_color (object, control)"] = []
    for _ in range(trials):
        direction = rng.normal(size=3)
        proj = pts @ direction
        a = proj < np.quantile(proj, 0.85)
        b = proj > np.quantile(proj, 0.15)
        cases["milk_color (object, control)"].append(_coloured_case(pts, colours, a, b, rng))
    return cases


def _coloured_case(pts: np.ndarray, colours: np.ndarray, a: np.ndarray, b: np.ndarray,
                   rng: np.random.Generator) -> dict:
    """Model = the points ``a``; target = the points ``b`` moved by a random rigid motion (5-30 degrees,
    translation 10 % of the extent), with 1 mm noise and colour noise 0.02."""
    rot = _rotation(rng, 5, 30)
    trans = rng.normal(size=3)
    trans *= 0.1 * _extent(pts) / np.linalg.norm(trans)
    target = pts[b] @ rot.T + trans + rng.normal(scale=0.001, size=(int(b.sum()), 3))
    trgb = np.clip(colours[b] + rng.normal(scale=0.02, size=(int(b.sum()), 3)), 0, 1)
    return {"model": pts[a], "model_rgb": colours[a], "target": target, "target_rgb": trgb,
            "rot": rot, "trans": trans, "extent": _extent(target)}


def _even(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return points[subsample_indices(points, n, rng, "voxel")]


def density_cases(root: Path, trials: int, rng: np.random.Generator, ratio: float) -> dict[str, list[dict]]:
    scenes = {"bunny (BCPD)": np.loadtxt(root / "pointsets3d" / "bunny_x.txt")}
    z = np.load(root / "pointsets3d" / "scans" / "office1.npz")
    office = z["xyz"].reshape(-1, 3).astype(np.float64)
    scenes["office1 frame"] = office[np.isfinite(office).all(1)]
    cases: dict[str, list[dict]] = {}
    for name, raw in scenes.items():
        base = _even(raw, 30000, rng)
        ext = _extent(base)
        cases[name] = []
        for _ in range(trials):
            d1, d2 = rng.normal(size=3), rng.normal(size=3)
            p1 = base @ d1
            keep_model = p1 < np.quantile(p1, 0.9)
            keep_target = p1 > np.quantile(p1, 0.1)
            # target: uniform, 1 point in 10 of the even base; model: `ratio` times denser on one side
            tgt = base[keep_target & (rng.random(len(base)) < 0.1)]
            p2 = base @ d2
            dense_side = p2 < np.median(p2)
            rate = np.where(dense_side, min(0.1 * ratio, 1.0), 0.1)
            mdl = base[keep_model & (rng.random(len(base)) < rate)]
            rot = _rotation(rng, 10, 45)
            trans = rng.normal(size=3)
            trans *= 0.1 * ext / np.linalg.norm(trans)
            target = tgt @ rot.T + trans + rng.normal(scale=0.005 * ext / np.sqrt(3), size=tgt.shape)
            cases[name].append({"model": mdl, "target": target, "rot": rot, "trans": trans,
                                "extent": _extent(target)})
    return cases


def outlier_cases(root: Path, trials: int, rng: np.random.Generator, fraction: float) -> list[dict]:
    raw = np.loadtxt(root / "pointsets3d" / "bunny_x.txt")
    base = _even(raw, 2000, rng)
    ext = _extent(base)
    cases = []
    for _ in range(trials):
        rot = _rotation(rng, 10, 45)
        trans = rng.normal(size=3)
        trans *= 0.1 * ext / np.linalg.norm(trans)
        inl = base @ rot.T + trans + rng.normal(scale=0.005 * ext / np.sqrt(3), size=base.shape)
        n_out = round(fraction / (1 - fraction) * len(inl))
        lo, hi = inl.min(0), inl.max(0)
        pad = 0.1 * (hi - lo)
        out = rng.uniform(lo - pad, hi + pad, size=(n_out, 3))
        target = np.r_[inl, out][rng.permutation(len(inl) + n_out)]
        cases.append({"model": base, "target": target, "rot": rot, "trans": trans, "extent": _extent(inl)})
    return cases


# ---------------------------------------------------------------------------------------------

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="../shared/data", type=Path)
    ap.add_argument("--quick", action="store_true", help="1 trial per case instead of 3")
    ap.add_argument("--trials", type=int, default=None)
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--init", default=None,
                    help="comma-separated starts of our methods (centroid, given, search, features); "
                         "default: each method's default")
    ap.add_argument("--no-peers", action="store_true", help="leave out cpd-rigid and Open3D")
    args = ap.parse_args()
    inits: list[str | None] = [None] if args.init is None else [i.strip() for i in args.init.split(",")]
    peers = not args.no_peers
    trials = args.trials or (1 if args.quick else 3)
    print(f"# Probabilistic rigid registration ({trials} trials per case; success = rot err < 2 deg and "
          f"mean point err < 1 % of the extent)")
    print(f"open3d: {o3d.__version__ if o3d is not None else 'not installed'}; "
          f"reglib from {Path(reglib.__file__).parent}")
    figs: dict[str, object] = {}
    cells: dict[str, dict[str, dict]] = {}

    # 1. colour
    methods = {**_ours_all(("color-gmm",), inits), **_geometry_methods(inits, peers=peers)}
    if o3d is not None and peers:
        methods["open3d colored icp"] = _o3d_colored_icp
    rows, colour_summary = [], {}
    for shift in (0.1, 0.25):
        for case, cs in colour_cases(args.data, trials, np.random.default_rng(1), shift, shift == 0.1).items():
            res = _run(methods, cs)
            label = case if case.startswith("milk") else f"{case}, offset {int(100 * shift)} %"
            colour_summary[label] = {k: float(np.mean(v["ok"])) for k, v in res.items()}
            cells[label] = res
            rows += [(f"{label} ({len(cs[0]['model'])} / {len(cs[0]['target'])} pts)", k, v) for k, v in res.items()]
    _table("1. colour: planar patches of real frames (geometry ambiguous in the plane)", rows)
    figs["color_gmm"] = ("success rate, planar patches (colour study)", colour_summary)

    # 2. density
    rows, dens_summary = [], {}
    for ratio in (1.0, 10.0):
        for case, cs in density_cases(args.data, trials, np.random.default_rng(2), ratio).items():
            res = _run(_geometry_methods(inits, peers=peers), cs)
            dens_summary[f"{case}, x{ratio:g}"] = {k: float(np.mean(v["ok"])) for k, v in res.items()}
            cells[f"{case}, density x{ratio:g}"] = res
            rows += [(f"{case}, density x{ratio:g} ({len(cs[0]['model'])} / {len(cs[0]['target'])} pts)", k, v)
                     for k, v in res.items()]
    _table("2. density: model sampled `ratio` times denser on one side", rows)
    figs["density_adaptive"] = ("success rate, density study", dens_summary)

    # 3. outliers
    rows, out_summary = [], {}
    for fraction in (0.0, 0.2, 0.35, 0.5):
        cs = outlier_cases(args.data, trials, np.random.default_rng(3), fraction)
        res = _run(_geometry_methods(inits, outliers=True, peers=peers), cs)
        out_summary[f"{int(100 * fraction)} %"] = {k: float(np.mean(v["ok"])) for k, v in res.items()}
        cells[f"bunny, {int(100 * fraction)} % outliers"] = res
        rows += [(f"bunny, {int(100 * fraction)} % outliers", k, v) for k, v in res.items()]
    _table("3. outliers: uniform outliers added to the target", rows)
    figs["bayes"] = ("success rate vs outlier share (bunny)", out_summary)
    if len(inits) > 1:
        _init_table(cells, inits)

    if not args.no_figures:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        FIGURES.mkdir(exist_ok=True)
        for key, (title, summary) in figs.items():
            cases = list(summary)
            names = list(next(iter(summary.values())))
            fig, ax = plt.subplots(figsize=(12, 4.5))
            width = 0.8 / len(names)
            for i, name in enumerate(names):
                ax.bar(np.arange(len(cases)) + i * width, [summary[c][name] for c in cases], width, label=name)
            ax.set_xticks(np.arange(len(cases)) + 0.4 - width / 2)
            ax.set_xticklabels([c.replace(" (object, control)", "") for c in cases], rotation=30,
                               fontsize=7, ha="right")
            ax.set_ylabel("success rate")
            ax.set_ylim(0, 1.05)
            ax.set_title(title)
            ax.legend(fontsize=7, ncol=3)
            fig.tight_layout()
            fig.savefig(FIGURES / f"prob_{key}.png", dpi=100)
            plt.close(fig)


if __name__ == "__main__":
    main()
