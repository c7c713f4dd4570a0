"""``reglib evaluate MATCH_OR_TRANSFORM.json LANDMARKS_A LANDMARKS_B``: landmark errors of a saved transform.

Prints TRE (mean / median / max), RMS, the Hausdorff distance, rTRE (with b's size) and the fold share
(with a's size); ``--out FILE`` writes :meth:`reglib._evaluate.Evaluation.to_dict` as JSON.
"""
from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._flags import out_file, read_transform_file

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

NAME = "evaluate"
HELP = ("landmark errors of a saved transform (a -> b): TRE per landmark and its mean / median / max, RMS, "
        "the Hausdorff distance, rTRE (TRE over b's diagonal) and the fold share over a; landmarks as text or CSV "
        "rows x y (with or without a header; an index column as ANHIR writes it is dropped), .npy, .ply or .pcd")

_TEXT_SUFFIXES = {".csv", ".txt", ".xyz"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("transform", type=Path, help="match.json (its shape_a / shape_b give the sizes) or "
                                                     "transform.json")
    parser.add_argument("landmarks_a", type=Path, help="landmarks of a, one point a row")
    parser.add_argument("landmarks_b", type=Path, help="the same landmarks in b, in the same order")
    parser.add_argument("--shape-a", type=int, nargs=2, metavar=("H", "W"),
                        help="size of a, for the fold share (default: match.json's shape_a)")
    parser.add_argument("--shape-b", type=int, nargs=2, metavar=("H", "W"),
                        help="size of b, for rTRE (default: match.json's shape_b)")
    parser.add_argument("--out", type=Path, help="write the evaluation as JSON here (its folder must exist)")


def run(args: argparse.Namespace) -> int:
    from .. import evaluate
    from ..errors import InputError

    out = None if args.out is None else out_file(args.out)
    body, given = read_transform_file(args.transform)
    shapes = {k: _shape(v) for k, v in given.items()}
    if not isinstance(body, dict):
        raise InputError(f"{args.transform.name}: expected a transform or match JSON object")
    shape_a = tuple(args.shape_a) if args.shape_a else shapes["shape_a"]
    shape_b = tuple(args.shape_b) if args.shape_b else shapes["shape_b"]
    ev = evaluate(body, read_landmarks(args.landmarks_a), read_landmarks(args.landmarks_b),
                  shape_a=shape_a, shape_b=shape_b)
    line = (f"{ev.n_landmarks} landmarks: TRE mean {ev.mean:.3f} median {ev.median:.3f} max {ev.max:.3f} px, "
            f"RMS {ev.rms:.3f} px, Hausdorff {ev.hausdorff:.3f} px")
    if ev.rtre_median is not None:
        line += f", rTRE median {ev.rtre_median:.5f} (mean {ev.rtre_mean:.5f}, max {ev.rtre_max:.5f})"
    if ev.fold_fraction is not None:
        line += f", folds {100 * ev.fold_fraction:.2f} % of a"
    print(line)
    if out is not None:
        from ..io import write_bytes_atomic

        write_bytes_atomic(out, (json.dumps(ev.to_dict(), indent=1) + "\n").encode())
        print(f"evaluation -> {out}")
    return 0


def _shape(value: Any) -> tuple[int, int] | None:
    """A match.json's shape_a / shape_b, or None when absent or unknown ([0, 0])."""
    if not isinstance(value, list) or len(value) != 2 or not all(isinstance(v, int) and v > 0 for v in value):
        return None
    return int(value[0]), int(value[1])


def read_landmarks(path: Path) -> np.ndarray:
    """(N, D) landmarks from a file: :func:`reglib.io.read_points`, and CSV / text rows with an ANHIR-style header
    whose first cell is empty (``,X,Y``) or an index column (0, 1, 2, ... before x, y), which is dropped.

    Raises
    ------
    InputError
        A missing or unreadable file, or rows that are not numbers.
    """
    import numpy as np

    from ..errors import InputError
    from ..io import read_points

    if not path.is_file():
        raise InputError(f"no such landmark file: {path}")
    if path.suffix.lower() not in _TEXT_SUFFIXES:
        return read_points(path)
    rows = _text_rows(path)
    header = rows[0] if rows and not _numbers(rows[0]) else None
    body = rows[1:] if header is not None else rows
    try:
        values = np.array([[float(c) for c in row] for row in body], dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{path.name}: not a numeric table of landmarks: {exc}") from None
    if values.ndim != 2 or (len(values) and values.shape[1] not in (2, 3, 4)):
        raise InputError(f"{path.name}: rows must have the same 2 or 3 coordinates (x y [z]), "
                         f"got {values.shape if values.ndim == 2 else 'rows of different lengths'}")
    if not len(values):
        return np.zeros((0, 2))
    indexed = values.shape[1] in (3, 4) and (
        (header is not None and header[0].strip() in ("", "index", "id"))
        or np.array_equal(values[:, 0], np.arange(len(values))))
    values = values[:, 1:] if indexed else values
    if values.shape[1] not in (2, 3):
        raise InputError(f"{path.name}: rows must be x y [z] (an index column first is allowed), "
                         f"got {values.shape[1]} columns")
    return values


def _text_rows(path: Path) -> list[list[str]]:
    """The non-empty, non-comment rows of a CSV (comma) or whitespace-separated text file, as cells."""
    from ..errors import InputError

    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path.name}: not a text file of landmarks") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if any("," in ln for ln in lines):
        return [[c.strip() for c in row] for row in csv.reader(lines)]
    return [ln.split() for ln in lines]


def _numbers(row: list[str]) -> bool:
    """Whether every cell of ``row`` reads as a number (a header row has a word in it)."""
    try:
        [float(cell) for cell in row]
    except ValueError:
        return False
    return True
