"""``reglib register MODEL TARGET --out FILE``: register two point sets without correspondences."""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from ..registration import METHODS
from ._flags import json_flag, out_file

NAME = "register"
HELP = "register a model point set onto a target (text, .npy, .ply or .pcd files of (x, y[, z]) points)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", type=Path, help="points to move: text (one point a line), .npy, .ply or .pcd "
                        "(an organized .pcd / (H, W, 3) .npy is a scan grid)")
    parser.add_argument("target", type=Path, help="points to move onto, same formats")
    parser.add_argument("--out", type=Path, required=True,
                        help="result: .json (the registration form of /v1/register), or .npy / .txt / .ply / .pcd "
                             "for the registered points (.ply / .pcd with the model's colours and normals, the "
                             "normals turned by the map; the JSON then goes next to it); its folder must exist")
    parser.add_argument("--method", default="l2e", choices=list(METHODS),
                        help="; ".join(f"{m.name}: {m.summary}" for m in METHODS.values()))
    parser.add_argument("--options", help="options of the method as a JSON object, e.g. '{\"loss\": \"cauchy\"}'")
    parser.add_argument("--no-rotation", action="store_true", help="l2e: skip the rotation search")
    parser.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from ..io import read_point_cloud, write_bytes_atomic, write_point_cloud
    from ..registration import register_points

    out = out_file(args.out)
    options = json_flag(args.options, "--options")
    if args.no_rotation and args.method == "l2e":
        options = {**(options or {}), "rotation": False}
    model, target = read_point_cloud(args.model), read_point_cloud(args.target)
    # the files' colors and normals where the method uses them; the model file's normals are left
    # out, as before register_points took clouds ("icp" would start checking pairs by them)
    res = register_points(replace(model, normals=None), target, method=args.method, options=options,
                          rng=args.seed)
    body = json.dumps(res.to_dict()).encode()
    if out.suffix.lower() == ".json":
        write_bytes_atomic(out, body)
    else:  # the model's colours and normals go along where the format holds them
        write_point_cloud(out, res.registered_cloud(model))
        write_bytes_atomic(out.with_suffix(".json"), body)
    matched = int((res.correspondence >= 0).sum())
    print(f"{args.method}: {matched}/{len(res.correspondence)} model points matched, {res.n_iter} iterations, "
          f"{'converged' if res.converged else 'not converged'} -> {out}")
    return 0
