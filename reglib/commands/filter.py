"""``reglib filter MATCHES --out FILE``: robustly filter putative matches stored in a file."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..errors import InputError

NAME = "filter"
HELP = "filter putative matches (.npz with src/dst, or a text file of x_a y_a x_b y_b rows)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("matches", type=Path, help=".npz with arrays src and dst, or whitespace text, 4 or 6 columns")
    parser.add_argument("--out", type=Path, required=True, help="JSON file for inliers, scores and the transform")
    parser.add_argument("--method", default="l2e", choices=["l2e", "vfc"])
    parser.add_argument("--seed", type=int, default=0)


def load_matches(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read (src, dst) from an .npz (keys src, dst) or a text table of 2D (4 columns) or 3D (6) rows."""
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as data:
            if "src" not in data or "dst" not in data:
                raise InputError(f"{path.name}: an .npz of matches needs arrays `src` and `dst`")
            return data["src"], data["dst"]
    try:
        table = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise InputError(f"{path.name}: not a numeric table: {exc}") from None
    if table.shape[1] not in (4, 6):
        raise InputError(f"{path.name}: expected 4 (2-D) or 6 (3-D) columns, got {table.shape[1]}")
    half = table.shape[1] // 2
    return table[:, :half], table[:, half:]


def run(args: argparse.Namespace) -> int:
    from ..robust import filter_matches

    src, dst = load_matches(args.matches)
    res = filter_matches(src, dst, method=args.method, rng=args.seed)
    body = {"n_matches": len(res.inliers), "n_inliers": res.n_inliers,
            "inliers": np.flatnonzero(res.inliers).tolist(), "scores": res.scores.tolist(),
            "transform": res.transform.to_dict(), "converged": res.converged, "reason": res.reason,
            "seed": args.seed, "sigma": res.sigma}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(body))
    print(f"{res.n_inliers}/{len(res.inliers)} inliers, sigma {res.sigma:.3g}, converged {res.converged} -> {args.out}")
    return 0
