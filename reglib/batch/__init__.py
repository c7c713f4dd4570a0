"""Batch jobs: match many image pairs listed in a manifest, on local processes or a Dask cluster.

>>> from reglib import batch                                           # doctest: +SKIP
>>> summary = batch.run("pairs.csv", "out/", executor=batch.LocalExecutor(workers=4))  # doctest: +SKIP

Each pair's files go to ``out/<id>/`` (``match.json`` written last marks it complete); a re-run
skips complete pairs, so a killed job is resumed by running it again. ``out/results.jsonl`` has one
summary line per pair. Dask is imported only when a :class:`DaskExecutor` starts.
"""
from ._job import BatchSummary, run
from .executors import DaskExecutor, Executor, LocalExecutor, WorkerLost
from .manifest import ManifestError, PairSpec, read_manifest
from .results import read_results

__all__ = ["BatchSummary", "DaskExecutor", "Executor", "LocalExecutor", "ManifestError", "PairSpec",
           "WorkerLost", "read_manifest", "read_results", "run"]
