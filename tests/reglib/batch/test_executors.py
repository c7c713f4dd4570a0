"""Executors: results come back for every task, task errors are results, dead workers are retried."""
from __future__ import annotations

import math
import multiprocessing
import os
import signal
import sys
from concurrent.futures import ProcessPoolExecutor

import pytest

from reglib.batch import DaskExecutor, LocalExecutor, WorkerLost
from reglib.errors import InputError

# A task function that kills its own worker process the first time it sees a task: the pool must
# be rebuilt and the task run again. Spawned workers import it by name, hence a real module file.
DIES_ONCE = '''
import os
from pathlib import Path

def dies_once(marker):
    path = Path(marker)
    if not path.exists():
        path.write_text("died")
        os._exit(13)
    return os.getpid()
'''


def test_local_executor_returns_every_result():
    with LocalExecutor(2) as executor:
        got = dict(executor.map_unordered(math.sqrt, [1.0, 4.0, 9.0, 16.0, 25.0]))
    assert got == {1.0: 1.0, 4.0: 2.0, 9.0: 3.0, 16.0: 4.0, 25.0: 5.0}


def test_local_executor_reports_a_task_error_as_its_result():
    with LocalExecutor(1) as executor:
        got = dict(executor.map_unordered(math.sqrt, [4.0, -1.0]))
    assert got[4.0] == 2.0
    assert isinstance(got[-1.0], ValueError)


def test_local_executor_retries_a_task_whose_worker_died(tmp_path, monkeypatch):
    (tmp_path / "reglib_test_dies_once.py").write_text(DIES_ONCE)
    monkeypatch.syspath_prepend(str(tmp_path))  # spawned workers get the parent's sys.path
    import reglib_test_dies_once

    try:
        marker = str(tmp_path / "marker")
        with LocalExecutor(1, retries=1) as executor:
            [(task, result)] = list(executor.map_unordered(reglib_test_dies_once.dies_once, [marker]))
        assert task == marker
        assert isinstance(result, int) and result != os.getpid()
    finally:
        sys.modules.pop("reglib_test_dies_once", None)


def test_local_executor_gives_up_after_the_retries():
    with LocalExecutor(1, retries=1) as executor:
        [(task, result)] = list(executor.map_unordered(os._exit, [3]))
    assert task == 3
    assert isinstance(result, WorkerLost)
    assert "2 attempt(s)" in str(result)


@pytest.mark.parametrize("kwargs, match", [
    ({"workers": 0}, "`workers` must be a positive integer"),
    ({"workers": 2, "retries": -1}, "`retries` must be a non-negative integer"),
])
def test_local_executor_rejects_bad_arguments(kwargs, match):
    with pytest.raises(InputError, match=match):
        LocalExecutor(**kwargs)


@pytest.mark.parametrize("args, kwargs, match", [
    ((), {}, "exactly one of"),
    (("tcp://127.0.0.1:8786",), {"local_workers": 2}, "exactly one of"),
    ((), {"local_workers": 0}, "`local_workers` must be a positive integer"),
])
def test_dask_executor_rejects_bad_arguments(args, kwargs, match):
    with pytest.raises(InputError, match=match):
        DaskExecutor(*args, **kwargs)


@pytest.mark.slow
def test_dask_local_cluster_returns_every_result_and_task_errors():
    with DaskExecutor(local_workers=2) as executor:
        assert executor.describe() == "dask LocalCluster x 2"
        got = dict(executor.map_unordered(math.sqrt, [4.0, 9.0, -1.0]))
    assert got[4.0] == 2.0 and got[9.0] == 3.0
    assert isinstance(got[-1.0], ValueError)


def _sigint_blocked() -> bool:
    return signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="no signal masks on this platform")
def test_a_worker_spawned_while_sigint_is_held_starts_with_it_held_and_the_job_gets_it_back():
    # A Ctrl-C reaching a worker before its initializer ignores SIGINT must stay pending, not print a traceback:
    # the worker inherits the block from the spawning thread; the job's own block ends with the context.
    from reglib.batch._executors import _sigint_held

    assert not _sigint_blocked()
    with _sigint_held(), ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        assert _sigint_blocked()
        assert pool.submit(_sigint_blocked).result(timeout=120)
    assert not _sigint_blocked()
