"""Images larger than memory: ``reglib match`` and ``reglib apply`` on a generated tiled TIFF pair.

    python benchmarks/bench_large.py --dir /tmp/large --size 20000            # the issue's size
    python benchmarks/bench_large.py --dir /tmp/large --size 6000 --opencv    # with OpenCV's in-memory remap

The pair (``_big_pair.BigPair``): a continuous texture written tile by tile, b = a under a known
smooth map of about ``--amplitude`` px. Each command runs in its own process; its wall time and
peak memory (the sum of the resident sizes of the process and its children, sampled every 0.1 s)
are printed. The transform's error is measured at 400 random points of a against the true map; the
tiled warp is compared on six random 256-px crops with b sampled at the transform's points
(bilinear, exact evaluation) and with ``warp_image`` on the same crop. ``--opencv`` also times the
in-memory way: b decoded whole, full-size float32 maps, one ``cv2.remap`` (where memory allows).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import psutil
import tifffile

sys.path.insert(0, str(Path(__file__).parent))
from _big_pair import BigPair  # noqa: E402

from reglib import KernelWarp, warp_image  # noqa: E402
from reglib.io import TiffRegions  # noqa: E402


def measured(cmd: list[str]) -> tuple[float, float, str]:
    """Run ``cmd``; its wall time (s), peak RSS of its process tree (MB) and output."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    root = psutil.Process(proc.pid)
    peak = 0
    while proc.poll() is None:
        try:
            tree = [root, *root.children(recursive=True)]
            peak = max(peak, sum(p.memory_info().rss for p in tree))
        except psutil.Error:
            pass
        time.sleep(0.1)
    out = proc.stdout.read() if proc.stdout else ""
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{out}")
    return time.perf_counter() - t0, peak / 2**20, out


def crops(warped: Path, b_path: Path, f: KernelWarp, size: int, seed: int = 0) -> list[tuple[float, float]]:
    """For six random 256-px crops of the warp: median |difference| to b sampled at f(p), and to warp_image."""
    rng = np.random.default_rng(seed)
    out = []
    with TiffRegions(warped) as w, TiffRegions(b_path) as b:
        for _ in range(6):
            y0, x0 = (int(v) for v in rng.integers(0, size - 256, 2))
            crop = w.read(y0, y0 + 256, x0, x0 + 256).astype(np.float64)
            yy, xx = np.mgrid[y0:y0 + 256, x0:x0 + 256]
            pos = f(np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float64))
            bx0, by0 = int(max(0, np.floor(pos[:, 0].min()) - 2)), int(max(0, np.floor(pos[:, 1].min()) - 2))
            bx1 = int(min(size, np.ceil(pos[:, 0].max()) + 3))
            by1 = int(min(size, np.ceil(pos[:, 1].max()) + 3))
            region = b.read(by0, by1, bx0, bx1).astype(np.float32)
            mx = (pos[:, 0] - bx0).reshape(256, 256).astype(np.float32)
            my = (pos[:, 1] - by0).reshape(256, 256).astype(np.float32)
            exact = cv2.remap(region, mx, my, cv2.INTER_LINEAR)
            inside = (mx >= 0) & (my >= 0) & (mx <= region.shape[1] - 1) & (my <= region.shape[0] - 1)
            d = f.to_dict()
            d["dst_mean"] = [d["dst_mean"][0] - bx0 * 1.0, d["dst_mean"][1] - by0 * 1.0]
            local = KernelWarp.from_dict(d).source_shifted((-x0, -y0))
            ref, _ = warp_image(b.read(by0, by1, bx0, bx1), local, (256, 256))
            out.append((float(np.median(np.abs(crop - exact)[inside])),
                        float(np.median(np.abs(crop - ref.astype(np.float64))[inside]))))
    return out


def opencv_remap(b_path: Path, f: KernelWarp, size: int) -> None:
    """The in-memory way: b whole, full-size float32 maps (filled band by band), one cv2.remap."""
    from reglib.dense import dense_flow

    b = tifffile.imread(b_path)
    maps = np.empty((size, size, 2), np.float32)
    for r0 in range(0, size, 1024):
        r1 = min(r0 + 1024, size)
        maps[r0:r1] = dense_flow(f.source_shifted((0, -r0)), (r1 - r0, size))
        maps[r0:r1, :, 0] += np.arange(size, dtype=np.float32)[None, :]
        maps[r0:r1, :, 1] += np.arange(r0, r1, dtype=np.float32)[:, None]
    warped = cv2.remap(b, maps, None, cv2.INTER_LINEAR)
    print(f"opencv remap done: {warped.shape}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, default=Path("/tmp/reglib_large"))
    parser.add_argument("--size", type=int, default=20000)
    parser.add_argument("--amplitude", type=float, default=25.0)
    parser.add_argument("--opencv", action="store_true", help="also time OpenCV's in-memory remap")
    parser.add_argument("--opencv-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    pair = BigPair(args.size, amplitude=args.amplitude)
    a_path, b_path = args.dir / "A.tif", args.dir / "B.tif"
    if args.opencv_only:
        f = KernelWarp.from_dict(json.loads((args.dir / "M" / "transform.json").read_text()))
        opencv_remap(b_path, f, args.size)
        return
    if not (a_path.exists() and b_path.exists()):
        t = time.perf_counter()
        pair.write(args.dir)
        print(f"generated {args.size}x{args.size} pair in {time.perf_counter() - t:.0f} s")
    reglib = [sys.executable, "-m", "reglib.cli"]
    t_match, rss_match, out = measured([*reglib, "match", str(a_path), str(b_path), "--out", str(args.dir / "M")])
    print(out.strip())
    f = KernelWarp.from_dict(json.loads((args.dir / "M" / "transform.json").read_text()))
    pts = np.random.default_rng(1).uniform(0, args.size - 1, (400, 2))
    err = np.linalg.norm(f(pts) - pair.true_map(pts), axis=1)
    print(f"match: {t_match:.1f} s, peak RSS {rss_match:.0f} MB; error at 400 points of a: median {np.median(err):.3f} "
          f"px, 90th percentile {np.percentile(err, 90):.3f} px, max {err.max():.3f} px")
    warped = args.dir / "W.tif"
    t_apply, rss_apply, out = measured([*reglib, "apply", str(args.dir / "M" / "transform.json"), str(b_path),
                                        "--out", str(warped), "--shape-a", str(args.size), str(args.size)])
    print(out.strip())
    shape = tifffile.imread(warped).shape if args.size <= 30000 else None  # the whole full-resolution image
    with tifffile.TiffFile(warped) as tif:
        page = tif.pages[0]
        print(f"W.tif: {page.shape} {page.dtype}, tiled {page.is_tiled}, {page.compression.name}, "
              f"{warped.stat().st_size / 2**20:.0f} MB{'' if shape is None else f', imread {shape}'}")
    print(f"apply: {t_apply:.1f} s, peak RSS {rss_apply:.0f} MB")
    for k, (exact, ref) in enumerate(crops(warped, b_path, f, args.size)):
        print(f"crop {k}: median |W - b(f(p))| {exact:.2f} grey levels, |W - warp_image| {ref:.2f}")
    if args.opencv:
        t_cv, rss_cv, out = measured([sys.executable, __file__, "--dir", str(args.dir), "--size", str(args.size),
                                      "--opencv-only"])
        print(f"opencv in-memory remap (b whole, full-size maps): {t_cv:.1f} s, peak RSS {rss_cv:.0f} MB")


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main()
