"""``reglib batch MANIFEST --out DIR``: match every pair of a manifest, resumably, locally or on Dask.

Exit status: 0 when every pair succeeded, 1 when some failed (each failure is recorded in
``DIR/<id>/error.json`` and ``DIR/results.jsonl``), 2 for a bad manifest, bad usage or an executor
that cannot start (then nothing is written), 130 after Ctrl-C (the workers stopped, ``results.jsonl``
rebuilt from what is on disk; running again resumes).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..outputs import FLOW_FORMATS

NAME = "batch"
HELP = "match every image pair of a manifest (CSV or JSON lines) into DIR/<id>/, resumably"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("manifest", type=Path,
                        help="CSV with header id,image_a,image_b[,option...] or .jsonl of objects; "
                             "relative paths are taken from the manifest's folder")
    parser.add_argument("--out", type=Path, required=True,
                        help="output folder: DIR/<id>/ per pair (match.json, transform.json, confidence.png; "
                             "more with --flow, --warped, --pictures), DIR/results.jsonl")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="N",
                       help="local worker processes (default: one per CPU)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on a Dask cluster, e.g. tcp://host:8786 (workers need reglib and the files)")
    where.add_argument("--dask-local", type=int, metavar="N", help="run on a Dask LocalCluster of N worker processes")
    parser.add_argument("--force", action="store_true", help="compute every pair again, even complete ones")
    parser.add_argument("--features", help="default features, e.g. sift (a row may override)")
    parser.add_argument("--method", help="default estimator: l2e or vfc (a row may override)")
    parser.add_argument("--seed", type=int, default=0, help="default seed, recorded in every result (default 0)")
    parser.add_argument("--flow", action="store_true", help="also save each pair's forward flow a -> b (flow.flo)")
    parser.add_argument("--flow-format", choices=FLOW_FORMATS, default=None,
                        help=f"file of that flow (implies --flow): {', '.join(FLOW_FORMATS)} (default flo; as "
                             "reglib match --flow-format)")
    parser.add_argument("--warped", action="store_true",
                        help="also save image b warped onto a (warped.png; for a TIFF over --max-pixels, warped.tif: "
                             "a tiled TIFF at full resolution written tile by tile)")
    parser.add_argument("--pictures", action="store_true",
                        help="also save the match drawing and the overlay (matches.png, overlay.png)")
    parser.add_argument("--retries", type=int, default=2,
                        help="extra attempts for a pair whose worker process died (default 2)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="progress bar on stderr (default: when stderr is a terminal)")


def run(args: argparse.Namespace) -> int:
    from ..batch import DaskExecutor, Executor, LocalExecutor
    from ..batch import run as run_batch

    # Bad counts are InputErrors from the executors: the CLI prints them and exits 2.
    executor: Executor
    if args.scheduler is not None or args.dask_local is not None:
        executor = DaskExecutor(args.scheduler, local_workers=args.dask_local, retries=args.retries)
    else:
        executor = LocalExecutor(args.workers, retries=args.retries)
    options: dict[str, object] = {"seed": args.seed}
    if args.features is not None:
        options["features"] = args.features
    if args.method is not None:
        options["method"] = args.method
    try:
        summary = run_batch(args.manifest, args.out, executor=executor, force=args.force, options=options,
                            flow=args.flow or args.flow_format is not None, warped=args.warped,
                            pictures=args.pictures, flow_format=args.flow_format or "flo", progress=args.progress)
    except KeyboardInterrupt:  # Ctrl-C: the workers are stopped and results.jsonl rebuilt; one line, not a traceback
        print(_interrupted(args.out), file=sys.stderr)
        return 130  # (the shell's status for a command ended by SIGINT)
    print(summary.table())
    print(f"results: {summary.results_path}")
    return 0 if summary.n_failed == 0 else 1


def _interrupted(out: Path) -> str:
    """The line for Ctrl-C: how many pairs are complete, and that running again resumes."""
    from ..batch import read_results

    results = out / "results.jsonl"
    try:
        records = read_results(results)
    except (OSError, ValueError):  # interrupted before the executor started: nothing was written
        return "reglib batch: interrupted before any pair ran; nothing was written"
    done = sum(record.get("status") == "ok" for record in records)
    return (f"reglib batch: interrupted: {done} of {len(records)} pairs complete ({results} says which); "
            "run the same command again to resume")
