"""The verdict against no motion (issue 49): how many answers the margin turns ``"unsupported"``, with and without it.

The margin (:attr:`reglib.dense.OverNoMotion.short_of_margin`) decides only ``converged`` / ``reason``, never the
transform (the margin modes: with a second try the "before" verdict recorded is the second try's), so each pair
runs once and its verdict is taken both ways (``after``: as the pipeline decides it;
``before``: with ``--before margin``, the margin of issue 49's first pass, z and share without the
neighbour test; with ``--before z``, without the margin, the rule z <= -4 alone). ``--before second_try``, the default
since issue 49's third pass: before is the first try's answer, ``"unsupported"``, where ``features="auto"`` ran its
second try on the haematoxylin channel (its transform too; every other pair's answer as it is). Three parts:

- ``--multimodal``: the 82 shared pairs (``<data>/multimodal``, as ``bench_multimodal.py``; success: mean landmark
  error under 5 px), ``match_images(a, b, features="multimodal", rng=0)`` (``--features auto``: with "auto").
- ``--families stain he``: the stain-like and H&E-like families (``_synthetic_pairs.py``), training and validation
  halves, ``match_images(a, b, features="auto", rng=0)``; success: median rTRE < 0.01.
- ``--forced he``: motions forced on the H&E-like pairs (the truth's least-squares affine map, it turned by +-5 /
  +-10 degrees or shifted by 6 % of the size, its mirror about no motion, turns of +-12 degrees): those whose
  landmark rTRE is above no motion's, and how the images rate them over no motion (structure fields as the
  multimodal dense stage correlates, and grey images).

Usage (from the project root)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_no_motion.py --multimodal --data ../shared/data
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_no_motion.py --families stain he
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_no_motion.py --forced he

Not run by CI.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _synthetic_pairs as sp
import bench_multimodal as bm

import reglib.matching._pipeline as pipeline
from reglib import evaluate, match_images
from reglib._transforms import KernelWarp, LinearPart
from reglib._verdict import UNSUPPORTED
from reglib.dense import rate_over_no_motion
from reglib.features import structure_image
from reglib.matching._dense import dense_options
from reglib.matching._inputs import read_images, run_of

_SEEN: dict = {}
_VERDICT = pipeline.image_verdict
_RATE = pipeline.rate_over_no_motion
_SECOND_TRY = pipeline._second_try
BEFORE = {"before": "second_try"}  # what "before" is: "z" (z <= -4 alone), "margin" (z and share, no neighbour
# test), or "second_try" (the first try's answer, as before the haematoxylin channel's second try)


def _rated(*args):
    """The pipeline's rating of the answer over no motion, recorded."""
    _SEEN["rating"] = _RATE(*args)
    return _SEEN["rating"]


def _both_verdicts(reason, converged, dense, evidence, threshold, *, short_of_margin=False):
    """The pipeline's verdict, recording the one before beside it (``BEFORE``: without the margin, or with the
    margin of issue 49's first pass: z and share, not the neighbour test)."""
    before = False
    if BEFORE["before"] == "margin" and "rating" in _SEEN:
        before = dataclasses.replace(_SEEN["rating"], neighbours=1.0).short_of_margin
    _SEEN["before"] = _VERDICT(reason, converged, dense, evidence, threshold, short_of_margin=before)
    return _VERDICT(reason, converged, dense, evidence, threshold, short_of_margin=short_of_margin)


def _second_try_recorded(images, run, sparse, dense, rating, sift=None):
    """The pipeline's second try, the first try's answer recorded."""
    _SEEN["first"] = dense.transform
    return _SECOND_TRY(images, run, sparse, dense, rating, sift)


pipeline.image_verdict = _both_verdicts
pipeline.rate_over_no_motion = _rated
pipeline._second_try = _second_try_recorded

FAMILIES = {"stain": (sp.make_stain_pair, sp.STAIN_TRAIN_SEEDS, sp.STAIN_VALIDATION_SEEDS),
            "he": (sp.make_he_pair, sp.HE_TRAIN_SEEDS, sp.HE_VALIDATION_SEEDS)}
HEAD = ["verdict", "pairs", "success", "median error", "converged among successes", "failures converged",
        "worse than no motion yet converged", "median wall s", "median CPU s"]


def _run(a, b, features: str) -> tuple:
    """(match, before verdict, before transform, wall s, CPU s) of one pair."""
    _SEEN.clear()
    t, c = time.perf_counter(), time.process_time()
    m = match_images(a, b, features=features, rng=0)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    if BEFORE["before"] == "second_try":
        if "first" in _SEEN:  # a second try ran: before it, the first answer, "unsupported"
            return m, (False, UNSUPPORTED), _SEEN["first"], wall, cpu
        return m, (m.converged, m.reason), m.transform, wall, cpu
    return m, _SEEN.get("before", (m.converged, m.reason)), m.transform, wall, cpu


def _rating() -> str:
    """The last answer's rating over no motion, in words (empty when none was measured)."""
    r = _SEEN.get("rating")
    return f" [z {r.z:.2f}, share {r.share:.3f}, neighbours {r.neighbours:.3f}]" if r is not None else ""


def _second_s(m, cpu: float) -> str:
    """The pair's CPU s and the second try's wall s, in words (empty when it did not run)."""
    second = m.timings_ms.get("second_try")
    return f" (CPU {cpu:.1f} s; second try {second / 1000:.1f} s wall)" if second is not None else ""


def _rows(label: str, errs: tuple[list, list], none: list, ok_below: float, verdicts: list, walls: list,
          cpus: list) -> list:
    out = []
    for tag, err, conv in (("before", errs[0], [v[0][0] for v in verdicts]),
                           ("after", errs[1], [v[1][0] for v in verdicts])):
        e, cv = np.array(err), np.array(conv)
        ok, worse = e < ok_below, e > np.array(none)
        out.append([f"{label}{tag}", len(e), f"{ok.mean():.1%}", f"{np.median(e):.4g}",
                    f"{int((cv & ok).sum())}/{int(ok.sum())}", int((cv & ~ok).sum()), int((cv & worse).sum()),
                    f"{np.median(walls):.1f}", f"{np.median(cpus):.1f}"])
    return out


def _print(head: list, rows: list) -> None:
    print("| " + " | ".join(head) + " |")
    print("|" + " --- |" * len(head))
    for r in rows:
        print("| " + " | ".join(str(x) for x in r) + " |")


def multimodal(data: Path, features: str = "multimodal") -> None:
    err, err0, none, verdicts, walls, cpus, moved = [], [], [], [], [], [], []
    for _, name, path in bm.load_pairs(data, None, False):
        land = np.loadtxt(path / "landmarks.txt")
        m, before, t0, wall, cpu = _run(bm.read(path / "a.png"), bm.read(path / "b.png"), features)
        err.append(bm.pair_error(m.transform, land))
        err0.append(bm.pair_error(t0, land))
        none.append(bm.pair_error(KernelWarp.identity(2), land))
        verdicts.append((before, (m.converged, m.reason)))
        walls.append(wall)
        cpus.append(cpu)
        if before != (m.converged, m.reason) or "first" in _SEEN:
            moved.append(f"{name} ({err0[-1]:.2f} -> {err[-1]:.2f} px): {before} -> {(m.converged, m.reason)}"
                         f"{_rating()}{_second_s(m, cpu)}")
    print(f"\n## The 82 multimodal pairs (features={features!r}; success: mean landmark error < 5 px)\n")
    _print(HEAD, _rows("", (err0, err), none, 5.0, verdicts, walls, cpus))
    print("\nverdicts moved or second tries run:", moved or "none")


def families(names: list[str]) -> None:
    rows, moved = [], []
    for fam in names:
        make, train, validation = FAMILIES[fam]
        for half, seeds in (("training", train), ("validation", validation)):
            err, err0, none, verdicts, walls, cpus = [], [], [], [], [], []
            for seed in seeds:
                pair = make(seed)
                la, lb = sp.landmarks(pair)
                m, before, t0, wall, cpu = _run(pair.a, pair.b, "auto")
                err.append(evaluate(m.transform, la, lb, shape_b=pair.b.shape[:2]).rtre_median)
                err0.append(evaluate(t0, la, lb, shape_b=pair.b.shape[:2]).rtre_median)
                none.append(evaluate(KernelWarp.identity(2), la, lb, shape_b=pair.b.shape[:2]).rtre_median)
                verdicts.append((before, (m.converged, m.reason)))
                walls.append(wall)
                cpus.append(cpu)
                if before != (m.converged, m.reason) or "first" in _SEEN:
                    moved.append(f"{pair.name} (rTRE {err0[-1]:.4f} -> {err[-1]:.4f}, no motion {none[-1]:.4f}): "
                                 f"{before} -> {(m.converged, m.reason)}{_rating()}{_second_s(m, cpu)}")
            rows += _rows(f"{fam} {half}, ", (err0, err), none, 0.01, verdicts, walls, cpus)
    print("\n## Stain-like families (features='auto'; success: median rTRE < 0.01)\n")
    _print(HEAD, rows)
    print("\nverdicts moved or second tries run:", moved or "none")


def _affine(matrix: np.ndarray) -> KernelWarp:
    return KernelWarp(dim=2, src_mean=np.zeros(2), src_scale=1.0, dst_mean=np.zeros(2), dst_scale=1.0,
                      linear=LinearPart(kind="affine", matrix=np.asarray(matrix, float)), beta=1.0,
                      centers=np.zeros((0, 2)), weights=np.zeros((0, 2)))


def _turn(c: np.ndarray, degrees: float, after: np.ndarray | None = None) -> np.ndarray:
    t = np.deg2rad(degrees)
    r = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    m = np.c_[r, c - r @ c]
    if after is None:
        return m
    return (np.r_[m, [[0, 0, 1]]] @ np.r_[after, [[0, 0, 1]]])[:2]


def _forced_motions(pair, la: np.ndarray, lb: np.ndarray) -> dict:
    a = np.linalg.lstsq(np.c_[la, np.ones(len(la))], lb, rcond=None)[0].T
    h, w = pair.b.shape[:2]
    c = np.array([w / 2, h / 2])
    out = {"truth_affine": a, "mirror": 2 * np.c_[np.eye(2), np.zeros(2)] - a}
    out.update({f"truth_turn{d}": _turn(c, d, a) for d in (-10, -5, 5, 10)})
    for k, s in enumerate([(0.06, 0), (0, 0.06), (-0.06, 0.04)]):
        m = a.copy()
        m[:, 2] += np.array(s) * [w, h]
        out[f"truth_shift{k}"] = m
    out.update({f"turn{d}": _turn(c, d) for d in (-12, 12)})
    return out


def forced(names: list[str]) -> None:
    rows = []
    for fam in names:
        make, train, validation = FAMILIES[fam]
        for half, seeds in (("training", train), ("validation", validation)):
            seen: dict = {"structure": [], "grey": []}
            for seed in seeds:
                pair = make(seed)
                la, lb = sp.landmarks(pair)
                run = run_of("multimodal", "l2e", None, 0)
                images = read_images(pair.a, pair.b, None, None, run)
                na, nb = images.normalized
                fields = {"structure": (structure_image(na, sigma=2.0), structure_image(nb, sigma=2.0)),
                          "grey": (images.gray_a, images.gray_b)}
                opts = dense_options(run.options, run.method)
                none = evaluate(KernelWarp.identity(2), la, lb, shape_b=pair.b.shape[:2]).rtre_median
                for matrix in _forced_motions(pair, la, lb).values():
                    t = _affine(matrix)
                    rtre = evaluate(t, la, lb, shape_b=pair.b.shape[:2]).rtre_median
                    for kind, (fa, fb) in fields.items():
                        r = rate_over_no_motion(fa, fb, t, opts)
                        seen[kind].append((rtre, none, r.z, r.share, r.z <= -4.0, r.z <= -4.0 or r.short_of_margin))
            for kind, got in seen.items():
                bad = [g for g in got if g[0] > g[1]]
                near = [g for g in got if g[0] < 0.01]
                rows.append([f"{fam} {half}", kind, len(bad), sum(g[4] for g in bad), sum(g[5] for g in bad),
                             f"{max(g[2] for g in bad):.2f}", f"{max(g[3] for g in bad):.3f}",
                             f"{sum(not g[5] for g in near)}/{len(near)}"])
    print("\n## Forced motions worse than no motion\n")
    _print(["family", "fields", "worse than no motion", "unsupported before (z <= -4)", "unsupported after",
            "their z, max", "their share, max", "rTRE < 0.01: converged after"], rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--multimodal", action="store_true")
    parser.add_argument("--families", nargs="*", default=[], choices=list(FAMILIES))
    parser.add_argument("--forced", nargs="*", default=[], choices=list(FAMILIES))
    parser.add_argument("--before", default="second_try", choices=["z", "margin", "second_try"],
                        help="the verdict compared with: z <= -4 alone, the margin without the neighbour test, or "
                             "the first try's answer before the haematoxylin channel's second try")
    parser.add_argument("--features", default="multimodal", choices=["multimodal", "auto"],
                        help="the features of the --multimodal part")
    args = parser.parse_args(argv)
    BEFORE["before"] = args.before
    if args.multimodal:
        multimodal(Path(args.data), args.features)
    if args.families:
        families(args.families)
    if args.forced:
        forced(args.forced)
    return 0


if __name__ == "__main__":
    sys.exit(main())
