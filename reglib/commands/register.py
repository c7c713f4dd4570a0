"""``reglib register MODEL TARGET --out FILE``: register two point sets without correspondences."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..errors import InputError

NAME = "register"
HELP = "register a model point set onto a target (text, .npy or ASCII .ply files of (x, y[, z]) points)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", type=Path, help="points to move: whitespace text (one point a line), .npy or ASCII .ply")
    parser.add_argument("target", type=Path, help="points to move onto, same formats")
    parser.add_argument("--out", type=Path, required=True,
                        help="result: .json (transform, registered points, correspondence), or .npy / .txt / .ply "
                             "for the registered points alone (the transform then goes next to it as .json)")
    parser.add_argument("--method", default="l2e", choices=["l2e", "cpd", "cpd-rigid", "cpd-affine"])
    parser.add_argument("--no-rotation", action="store_true", help="l2e: skip the rotation search")
    parser.add_argument("--seed", type=int, default=0)


def load_points(path: Path) -> np.ndarray:
    """Read an (N, D) point array from .npy, ASCII .ply (vertex x y z) or whitespace text."""
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except ValueError as exc:
            raise InputError(f"{path.name}: not a numeric .npy array: {exc}") from None
    if suffix == ".ply":
        return _read_ply(path)
    try:
        return np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise InputError(f"{path.name}: not a numeric table: {exc}") from None


def _read_ply(path: Path) -> np.ndarray:
    lines = path.read_text(errors="replace").splitlines()
    if not lines or lines[0].strip() != "ply":
        raise InputError(f"{path.name}: not a PLY file")
    n_vertex, props, in_vertex, header_end = None, [], False, None
    for i, line in enumerate(lines[1:], start=1):
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and words[1] != "ascii":
            raise InputError(f"{path.name}: only ASCII PLY is supported, got {words[1]}")
        if words[0] == "element":
            in_vertex = words[1] == "vertex"
            if in_vertex:
                n_vertex = int(words[2])
        elif words[0] == "property" and in_vertex:
            props.append(words[-1])
        elif words[0] == "end_header":
            header_end = i
            break
    if header_end is None or n_vertex is None or not {"x", "y"} <= set(props):
        raise InputError(f"{path.name}: PLY header needs a vertex element with x and y properties")
    cols = [props.index(c) for c in ("x", "y", "z") if c in props]
    try:
        table = np.array([lines[header_end + 1 + k].split() for k in range(n_vertex)], dtype=np.float64)
    except (ValueError, IndexError) as exc:
        raise InputError(f"{path.name}: malformed vertex data: {exc}") from None
    return table[:, cols]


def save_points(path: Path, points: np.ndarray) -> None:
    suffix = path.suffix.lower()
    if suffix == ".npy":
        np.save(path, points)
    elif suffix == ".ply":
        pts = points if points.shape[1] == 3 else np.c_[points, np.zeros(len(points))]
        header = f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
        path.write_text(header + "\n".join(" ".join(repr(float(v)) for v in row) for row in pts) + "\n")
    else:
        np.savetxt(path, points, fmt="%.17g")


def run(args: argparse.Namespace) -> int:
    from ..registration import register_points

    model, target = load_points(args.model), load_points(args.target)
    options = {"rotation": False} if args.no_rotation and args.method == "l2e" else None
    res = register_points(model, target, method=args.method, options=options, rng=args.seed)
    registered = res.transform(model)
    body = {"registered": registered.tolist(), "correspondence": res.correspondence.tolist(),
            "transform": res.transform.to_dict(), "converged": res.converged, "n_iter": res.n_iter,
            "method": args.method, "seed": args.seed}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.out.suffix.lower() == ".json":
        args.out.write_text(json.dumps(body))
    else:
        save_points(args.out, registered)
        args.out.with_suffix(".json").write_text(json.dumps(body))
    matched = int((res.correspondence >= 0).sum())
    print(f"{args.method}: {matched}/{len(model)} model points matched, {res.n_iter} iterations, "
          f"converged {res.converged} -> {args.out}")
    return 0
