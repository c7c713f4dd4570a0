"""``reglib filter MATCHES --out FILE``: robustly filter putative matches stored in a file."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..robust import METHODS
from ._flags import json_flag, out_file

NAME = "filter"
HELP = "filter putative matches (.npz with src/dst, or a text / CSV file of x_a y_a x_b y_b rows)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("matches", type=Path,
                        help=".npz with arrays src and dst, or text (whitespace; commas for .csv) of 4 (2-D) or "
                             "6 (3-D) columns; a first row of non-numbers is a header")
    parser.add_argument("--out", type=Path, required=True,
                        help="JSON file: the filter-result form of /v1/filter (inliers, scores, transform, ...); "
                             "its folder must exist")
    parser.add_argument("--method", default="l2e", choices=list(METHODS))
    parser.add_argument("--options", help="estimator options as a JSON object, e.g. '{\"linear\": \"none\"}'")
    parser.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from ..io import read_matches, write_bytes_atomic
    from ..robust import filter_matches

    out = out_file(args.out)
    options = json_flag(args.options, "--options")
    src, dst = read_matches(args.matches)
    res = filter_matches(src, dst, method=args.method, options=options, rng=args.seed)
    write_bytes_atomic(out, json.dumps(res.to_dict()).encode())
    status = "converged" if res.converged else f"not converged ({res.reason or 'iteration cap'})"
    print(f"{res.n_inliers}/{res.n_matches} inliers, sigma {res.sigma:.3g}, {status} -> {out}")
    return 0
