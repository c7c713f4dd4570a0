"""The unit of batch work, run inside a worker process: match one pair and leave its files in OUT/<id>/.

The files of a pair (:func:`save_pair`): ``transform.json``, ``confidence.png`` (when the match has a
confidence map), with ``flow`` ``flow.flo`` (or ``flow.mha``, ... by ``flow_format``), with ``warped``
``warped.png``, with ``pictures`` ``matches.png`` and ``overlay.png``, and ``match.json`` last: the
names of ``reglib match --out``. A match that did not converge gets no flow, confidence, warped image or
overlay (:func:`reglib.outputs.writes_motion`), as from ``reglib match``. A pair with a TIFF over
``max_pixels`` is matched at a working size; with ``warped`` it gets ``warped.tif``, a tiled TIFF at full
resolution written tile by tile, its pictures are drawn at a reduced size, and it gets no flow
(:mod:`reglib._large_outputs`).
"""
from __future__ import annotations

import dataclasses
import traceback
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ._manifest import PairSpec
from ._results import ERROR_FILE, MATCH_FILE, pair_dir, publish_pair, write_json_atomic

__all__ = ["PairTask", "process_pair", "record_failure", "save_pair"]

_worker_ready = False


def _setup_worker() -> None:
    """Once per worker process: OpenCV single-threaded, as parallelism comes from the processes,
    and freed memory kept for the next pair (:func:`reglib.worker.prepare_worker_process`)."""
    global _worker_ready
    if not _worker_ready:
        from ..worker import prepare_worker_process

        prepare_worker_process()
        _worker_ready = True


@dataclasses.dataclass(frozen=True, slots=True)
class PairTask:
    """Everything a worker needs for one pair: paths and options, no arrays."""

    pair: PairSpec
    out: str
    options: Mapping[str, Any]  # the job's defaults overlaid with the row's, already checked
    flow: bool = False
    warped: bool = False
    pictures: bool = False
    flow_format: str = "flo"  # the suffix of flow.<format>, written by reglib.io.write_flow


def record_failure(out: Path, pair_id: str, message: str, *, details: str | None = None) -> dict[str, Any]:
    """Make ``OUT/<id>/`` hold only ``error.json`` (replacing any earlier files) and return the pair's results line."""
    body = {"id": pair_id, "status": "failed", "error": message, "details": details}
    publish_pair(out, pair_id, lambda folder: write_json_atomic(folder / ERROR_FILE, body))
    return {"id": pair_id, "status": "failed", "n_matches": None, "n_inliers": None, "timings_ms": None,
            "error": message}


def save_pair(folder: Path, match: Any, task: PairTask, image_a: Any, image_b: Any, max_pixels: int) -> None:
    """Write the files of one matched pair into ``folder`` (see the module docstring), ``match.json`` last."""
    from ..outputs import save_match

    save_match(match, folder, image_a=image_a if task.pictures else None,
               image_b=image_b if task.warped or task.pictures else None,
               flow=task.flow, flow_format=task.flow_format, warped=task.warped, pictures=task.pictures,
               max_pixels=max_pixels)


def process_pair(task: PairTask) -> dict[str, Any]:
    """Match one pair and save it (:func:`save_pair`); a failure is recorded, not raised.

    Returns the pair's ``results.jsonl`` line. The pair's folder appears only with its files in it
    (:func:`~reglib.batch._results.publish_pair`), replacing an earlier attempt's whole, so
    ``match.json`` and ``error.json`` never both describe the pair.
    """
    from ..io import is_large_tiff, read_image
    from ..matching import MatchRequest

    _setup_worker()
    out = Path(task.out)
    pair = task.pair
    folder = pair_dir(out, pair.id)
    (folder / MATCH_FILE).unlink(missing_ok=True)  # an earlier result: from here on the pair counts as not done
    try:
        request = MatchRequest.from_fields(task.options, what="options")
        image_a: Any = pair.image_a
        image_b: Any = pair.image_b
        limit = request.options.max_pixels
        # a TIFF over the limit stays a path: matched at a working size, warped tile by tile (warped.tif)
        large = is_large_tiff(image_a, limit) or is_large_tiff(image_b, limit)
        if (task.warped or task.pictures) and not large:  # save_match needs the pixels too: decode each file once
            image_a = read_image(image_a, max_pixels=limit, name="image_a")
            image_b = read_image(image_b, max_pixels=limit, name="image_b")
        match = request.run(image_a, image_b)
        publish_pair(out, pair.id, lambda staging: save_pair(staging, match, task, image_a, image_b, limit))
    except Exception as exc:  # any failure of one pair is that pair's result; the job goes on
        return record_failure(out, pair.id, f"{type(exc).__name__}: {exc}", details=traceback.format_exc())
    return {"id": pair.id, "status": "ok", "n_matches": match.n_matches, "n_inliers": match.n_inliers,
            "converged": bool(match.converged), "reason": match.reason, "timings_ms": dict(match.timings_ms),
            "error": None}
