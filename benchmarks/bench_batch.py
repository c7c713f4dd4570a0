"""Batch throughput: pairs/s with 1 and 2 local worker processes and a 2-worker Dask LocalCluster, and the
per-pair overhead of the batch machinery against calling ``match_images`` + ``save_match`` in a loop.

    .venv/bin/python benchmarks/bench_batch.py --pairs 200          # the issue's size
    .venv/bin/python benchmarks/bench_batch.py                      # 24 pairs: a few minutes on 2 cores

Pairs are 640x480 crops of scikit-image samples, b = a moved by a random similarity. Every mode
writes the same files (match.json and transform.json per pair) into a fresh folder. Dense
refinement is off by default (``--dense`` turns it on): it multiplies the per-pair work by ~10 and
the batch overhead is what this measures. BLAS and OpenCV run single-threaded everywhere, the loop
included, so the comparison is process for process.
"""
from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_name] = "1"  # before numpy loads: the in-process loop runs like one worker

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from skimage import data  # noqa: E402

from reglib import batch, match_images  # noqa: E402
from reglib.outputs import save_match  # noqa: E402

SAMPLES = ("astronaut", "coffee", "chelsea", "rocket", "camera", "immunohistochemistry")


def make_pairs(folder: Path, count: int, size: tuple[int, int], seed: int) -> Path:
    """Write ``count`` pairs and a CSV manifest; return the manifest path."""
    rng = np.random.default_rng(seed)
    width, height = size
    rows = ["id,image_a,image_b"]
    for k in range(count):
        image = getattr(data, SAMPLES[k % len(SAMPLES)])()
        if image.ndim == 2:
            image = np.dstack([image] * 3)
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        angle = np.deg2rad(rng.uniform(-15, 15))
        scale = rng.uniform(0.9, 1.1)
        motion = cv2.getRotationMatrix2D((width / 2, height / 2), np.rad2deg(angle), scale)
        motion[:, 2] += rng.uniform(-0.04, 0.04, 2) * size
        moved = cv2.warpAffine(image, motion, size, borderMode=cv2.BORDER_REFLECT)
        cv2.imwrite(str(folder / f"{k:04d}_a.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / f"{k:04d}_b.png"), cv2.cvtColor(moved, cv2.COLOR_RGB2BGR))
        rows.append(f"p{k:04d},{k:04d}_a.png,{k:04d}_b.png")
    manifest = folder / "pairs.csv"
    manifest.write_text("\n".join(rows) + "\n")
    return manifest


def run_loop(manifest: Path, out: Path, options: dict) -> float:
    """The baseline: the same work, one pair after another, in this process."""
    cv2.setNumThreads(1)
    pairs = batch.read_manifest(manifest)
    start = time.perf_counter()
    for pair in pairs:
        match = match_images(pair.image_a, pair.image_b, options=options, rng=0)
        save_match(match, out / pair.id, flow=False, warped=False, pictures=False)
    return time.perf_counter() - start


def run_batch(manifest: Path, out: Path, options: dict, executor: batch.Executor) -> float:
    start = time.perf_counter()
    with executor:  # workers started inside the timing: a job pays for them
        summary = batch.run(manifest, out, executor=executor, options=options, progress=False)
    seconds = time.perf_counter() - start
    if summary.n_failed:
        raise SystemExit(f"{summary.n_failed} pair(s) failed:\n{summary.table()}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=24)
    parser.add_argument("--size", default="640x480", help="W x H of every image")
    parser.add_argument("--dense", action="store_true", help="with dense refinement (about 10x the work per pair)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))
    options = {"dense": args.dense}
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        root = Path(tmp)
        (root / "pairs").mkdir()
        manifest = make_pairs(root / "pairs", args.pairs, size, args.seed)  # type: ignore[arg-type]
        modes = [
            ("loop: match_images + save_match", lambda out: run_loop(manifest, out, options)),
            ("batch, local processes x 1", lambda out: run_batch(manifest, out, options, batch.LocalExecutor(1))),
            ("batch, local processes x 2", lambda out: run_batch(manifest, out, options, batch.LocalExecutor(2))),
            ("batch, Dask LocalCluster x 1",
             lambda out: run_batch(manifest, out, options, batch.DaskExecutor(local_workers=1))),
            ("batch, Dask LocalCluster x 2",
             lambda out: run_batch(manifest, out, options, batch.DaskExecutor(local_workers=2))),
        ]
        seconds = {}
        for number, (name, fn) in enumerate(modes):
            seconds[name] = fn(root / f"out{number}")
            print(f"  {name}: {seconds[name]:.1f} s", flush=True)
    loop, one = seconds[modes[0][0]], seconds[modes[1][0]]
    local = {name.rsplit(" ", 1)[1]: s for name, s in seconds.items() if "local processes" in name}
    print(f"\n{args.pairs} pairs of {size[0]}x{size[1]}, dense {'on' if args.dense else 'off'}, "
          f"{os.cpu_count()} CPUs\n")
    print("| mode | seconds | pairs/s | speed-up vs local x 1 | time vs local, same workers "
          "| overhead per pair vs loop (1 worker) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, _ in modes:
        s = seconds[name]
        workers = name.rsplit(" ", 1)[1]
        versus_local = f"{s / local[workers]:.2f}x" if "Dask" in name else "-"
        overhead = f"{(s - loop) / args.pairs * 1000:+.0f} ms" if name != modes[0][0] and workers == "1" else "-"
        print(f"| {name} | {s:.1f} | {args.pairs / s:.2f} | {one / s:.2f}x | {versus_local} | {overhead} |")


if __name__ == "__main__":
    main()
