"""The batch job: read the manifest, skip finished pairs, run the rest on an executor, summarise."""
from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..outputs import FLOW_FORMATS
from ._executors import Executor, LocalExecutor
from ._manifest import check_options, read_manifest
from ._results import RESULTS_FILE, format_summary, load_match, pair_dir, rebuild_results, remove_leftovers
from ._work import PairTask, process_pair, record_failure

__all__ = ["BatchSummary", "FLOW_FORMATS", "run"]


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class BatchSummary:
    """What a batch run did. ``records`` are the ``results.jsonl`` lines, in manifest order."""

    records: tuple[dict[str, Any], ...]
    skipped: int  # pairs already complete before this run, not computed again
    seconds: float
    executor: str
    results_path: Path

    @property
    def n_ok(self) -> int:
        return sum(record["status"] == "ok" for record in self.records)

    @property
    def n_failed(self) -> int:
        return len(self.records) - self.n_ok

    @property
    def n_not_converged(self) -> int:
        """Pairs that ran (status ok) but whose answer says ``converged=False`` (each row has its ``reason``)."""
        return sum(record["status"] == "ok" and not record["converged"] for record in self.records)

    def table(self) -> str:
        """The human summary printed at the end of ``reglib batch``."""
        return format_summary(self.records, skipped=self.skipped, seconds=self.seconds, executor=self.executor)


def _progress(total: int, enabled: bool | None) -> Any:
    try:
        from tqdm import tqdm
    except ImportError:  # the bar is a convenience; the job runs without it
        return None
    # disable=None: tqdm shows the bar only on a terminal
    return tqdm(total=total, unit="pair", desc="batch", dynamic_ncols=True, file=sys.stderr,
                disable=None if enabled is None else not enabled)


def _follow(executor: Executor, tasks: list[PairTask], out: Path, bar: Any) -> None:
    """Run ``tasks`` on the started ``executor``, appending each pair's line to ``results.jsonl`` as it ends."""
    if not tasks:
        return
    failed = 0
    with (out / RESULTS_FILE).open("a", encoding="utf-8") as live:
        for task, result in executor.map_unordered(process_pair, tasks):
            if isinstance(result, BaseException):  # the worker died, or the task could not even start
                result = record_failure(out, task.pair.id, f"{type(result).__name__}: {result}")
            failed += result["status"] != "ok"
            live.write(json.dumps(result) + "\n")
            live.flush()
            if bar is not None:
                bar.set_postfix(failed=failed, refresh=False)
                bar.update()


def run(manifest: str | Path, out: str | Path, *, executor: Executor | None = None,
        force: bool = False, options: Mapping[str, Any] | None = None, flow: bool = False,
        warped: bool = False, pictures: bool = False, flow_format: str = "flo",
        progress: bool | None = None) -> BatchSummary:
    """Match every pair of a manifest, writing ``OUT/<id>/`` per pair and ``OUT/results.jsonl``.

    Parameters
    ----------
    manifest : str or Path
        A manifest file (see :mod:`reglib.batch._manifest`): CSV or JSON lines.
    out : str or Path
        Output folder, created once the executor has started. Each pair's files go to ``out/<id>/``
        with the file names of ``reglib match --out``: by default ``match.json``, ``transform.json``
        and ``confidence.png`` (when the match has a confidence map); more with ``flow``, ``warped``
        and ``pictures``. A pair's folder appears whole, once its files are written; nothing is
        written outside ``out``.
    executor : Executor, optional
        Where the pairs run; default :class:`LocalExecutor` with one process per CPU. It is started
        and closed by this call; when it cannot start, nothing is written.
    force : bool
        Compute every pair again; by default pairs whose ``match.json`` is complete are skipped.
    options : mapping, optional
        Defaults for every pair (``features``, ``method``, ``seed`` and fields of
        :class:`reglib.MatchOptions`); a manifest row's own options override them. ``seed`` is 0
        unless given, so a run is reproducible.
    flow, warped, pictures : bool
        Also save, per pair, the dense forward flow (``flow.flo``, Middlebury), image b warped onto
        image a (``warped.png``), and the match drawing and overlay (``matches.png``, ``overlay.png``).
    flow_format : str
        The flow file with ``flow``: ``"flo"`` (``flow.flo``, Middlebury), ``"npy"``, or an ITK
        displacement field, ``"mha"``, ``"nrrd"``, ``"nii"``, ``"nii.gz"`` (see :func:`reglib.io.write_flow`).
    progress : bool, optional
        Show a progress bar on stderr; default: only when stderr is a terminal.

    Returns
    -------
    BatchSummary

    Raises
    ------
    ManifestError
        When any manifest row is bad (every bad row is listed); nothing runs.
    InputError
        For bad ``options`` or an ``out`` that is not a folder.
    ExecutorStartError
        When the executor cannot start (e.g. no Dask scheduler at the address); nothing is written.
    """
    pairs = read_manifest(manifest)
    defaults = check_options(options or {})
    if flow_format not in FLOW_FORMATS:  # (a shell: the check in its own words, not the library's helper)
        raise InputError(f"`flow_format` must be one of {list(FLOW_FORMATS)}, got {flow_format!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"`out` must be a folder, got a file: {out}")
    ids = [pair.id for pair in pairs]
    for pair_id in ids:
        pair_dir(out, pair_id)  # refuse, before any work, an id or symlink that leads outside `out`
    todo = [pair for pair in pairs if force or load_match(out / pair.id) is None]
    skipped = len(pairs) - len(todo)
    todo_ids = {pair.id for pair in todo}
    tasks = [PairTask(pair, str(out.resolve()), {**defaults, **pair.options}, flow, warped, pictures, flow_format)
             for pair in todo]
    executor = executor or LocalExecutor()
    started = time.perf_counter()
    begun = False
    try:
        with contextlib.ExitStack() as stack:
            if tasks:  # not even started when there is nothing to do; a start that fails leaves nothing behind
                stack.enter_context(executor)
            out.mkdir(parents=True, exist_ok=True)
            begun = True
            remove_leftovers(out, ids)
            # Start the live file from what is already done; this also drops a line a killed run left half-written.
            rebuild_results(out, [pair_id for pair_id in ids if pair_id not in todo_ids])
            bar = _progress(len(tasks), progress)
            if bar is not None:
                stack.callback(bar.close)
            _follow(executor, tasks, out, bar)
    finally:
        if begun:  # after the executor stopped (also on Ctrl-C): no worker writes a pair after this reads them
            records = rebuild_results(out, ids)
    return BatchSummary(records=tuple(records), skipped=skipped, seconds=time.perf_counter() - started,
                        executor=executor.describe(), results_path=out / RESULTS_FILE)
