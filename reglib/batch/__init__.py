"""Batch jobs: match many image pairs listed in a manifest, on local processes or a Dask cluster.

>>> from reglib import batch                                           # doctest: +SKIP
>>> summary = batch.run("pairs.csv", "out/", executor=batch.LocalExecutor(workers=4))  # doctest: +SKIP

Each pair's files go to ``out/<id>/`` (``match.json``, ``transform.json``, ``confidence.png``; the
flow, the warped image and pictures on request, named as by ``reglib match --out``); the folder
appears whole once they are written, ``match.json`` marking it complete. A re-run skips complete
pairs, so a killed job is resumed by running it again. ``out/results.jsonl`` has one summary line
per pair; it is written only once the executor has started. Dask is imported only when a
:class:`DaskExecutor` starts.
"""
from ._executors import DaskExecutor, Executor, ExecutorStartError, LocalExecutor, WorkerLost
from ._job import FLOW_FORMATS, BatchSummary, run
from ._manifest import ManifestError, PairSpec, read_manifest
from ._results import read_results

__all__ = ["FLOW_FORMATS", "BatchSummary", "DaskExecutor", "Executor", "ExecutorStartError", "LocalExecutor",
           "ManifestError", "PairSpec", "WorkerLost", "read_manifest", "read_results", "run"]
