"""``reglib filter MATCHES --out FILE``: robustly filter putative matches stored in a file."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..robust import METHODS
from ._flags import json_flag

NAME = "filter"
HELP = "filter putative matches (.npz with src/dst, or a text file of x_a y_a x_b y_b rows)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("matches", type=Path, help=".npz with arrays src and dst, or whitespace text, 4 or 6 columns")
    parser.add_argument("--out", type=Path, required=True,
                        help="JSON file: the filter-result form of /v1/filter (inliers, scores, transform, ...)")
    parser.add_argument("--method", default="l2e", choices=list(METHODS))
    parser.add_argument("--options", help="estimator options as a JSON object, e.g. '{\"linear\": \"none\"}'")
    parser.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from ..io import read_matches, write_bytes_atomic
    from ..robust import filter_matches

    options = json_flag(args.options, "--options")
    src, dst = read_matches(args.matches)
    res = filter_matches(src, dst, method=args.method, options=options, rng=args.seed)
    write_bytes_atomic(args.out, json.dumps(res.to_dict()).encode())
    print(f"{res.n_inliers}/{res.n_matches} inliers, sigma {res.sigma:.3g}, converged {res.converged} -> {args.out}")
    return 0
