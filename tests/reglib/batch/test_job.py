"""Whole batch jobs on generated pairs: local processes and Dask agree, failures are recorded, a killed
job resumes without redoing finished pairs, and nothing is written outside the output folder."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from reglib import KernelWarp, batch, match_images
from reglib.batch._results import load_match
from reglib.cli import main

from .conftest import write_csv, write_pairs

FAST = {"dense": False}  # the sparse stage only: these tests are about the job, not the accuracy


def _match(out: Path, pair_id: str) -> dict:
    return json.loads((out / pair_id / "match.json").read_text())


def _assert_same_match(got: dict, want: dict) -> None:
    """Equal as CONTRACTS.md asks of the same request anywhere: floats to 1e-9 relative; timings aside.

    (Dask workers run BLAS single-threaded, so sums may be added in another order.)
    """
    got, want = dict(got), dict(want)
    assert got.pop("timings_ms").keys() == want.pop("timings_ms").keys()
    _assert_close(got, want, "match")


def _assert_close(got: object, want: object, where: str) -> None:
    if isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), where
        for key in want:
            _assert_close(got[key], want[key], f"{where}.{key}")
    elif isinstance(want, list) and want and not isinstance(want[0], (dict, str)):
        np.testing.assert_allclose(np.asarray(got, dtype=float), np.asarray(want, dtype=float), rtol=1e-9,
                                   atol=1e-12, err_msg=where)
    elif isinstance(want, float):
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12), where
    else:
        assert got == want, where


@pytest.mark.slow
def test_local_processes_and_a_dask_cluster_give_the_same_answer_as_the_library(pairs_folder, tmp_path):
    folder, rows = pairs_folder
    manifest = write_csv(folder / "four.csv", [(*row, "7") for row in rows[:4]], header="id,image_a,image_b,seed")
    local = batch.run(manifest, tmp_path / "local", executor=batch.LocalExecutor(2), options=FAST, progress=False)
    dask = batch.run(manifest, tmp_path / "dask", executor=batch.DaskExecutor(local_workers=2), options=FAST,
                     progress=False)
    assert (local.n_ok, local.n_failed, dask.n_ok, dask.n_failed) == (4, 0, 4, 0)
    assert dask.executor == "dask LocalCluster x 2"
    for pair_id, image_a, image_b in rows[:4]:
        got = _match(tmp_path / "local", pair_id)
        assert got["seed"] == 7
        _assert_same_match(_match(tmp_path / "dask", pair_id), got)
        # This process runs BLAS multi-threaded, the workers single-threaded: the ill-conditioned kernel
        # weights may differ in their last digits, the matches and the mapping may not.
        want = match_images(folder / image_a, folder / image_b, options=FAST, rng=7).to_dict()
        for key in ("n_matches", "n_inliers", "inliers", "src", "dst", "converged", "reason", "seed"):
            assert got[key] == want[key], key
        mapped = KernelWarp.from_dict(got["transform"])(np.asarray(want["src"]))
        np.testing.assert_allclose(mapped, KernelWarp.from_dict(want["transform"])(np.asarray(want["src"])), atol=1e-6)
    lines = batch.read_results(tmp_path / "dask" / "results.jsonl")
    assert [line["id"] for line in lines] == [row[0] for row in rows[:4]]
    assert all(line["status"] == "ok" and line["error"] is None and line["n_inliers"] > 0 for line in lines)
    for line in lines:  # every pair that ran says whether its answer may be used, and why not
        got = _match(tmp_path / "dask", line["id"])
        assert (line["converged"], line["reason"]) == (got["converged"], got["reason"])
        assert line["converged"] == (line["reason"] is None)


def test_a_failing_pair_is_recorded_and_the_job_goes_on(pairs_folder, tmp_path, capsys):
    folder, rows = pairs_folder
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n not really a png")
    manifest = write_csv(tmp_path / "m.csv", [
        (rows[0][0], str(folder / rows[0][1]), str(folder / rows[0][2])),
        ("broken", "broken.png", str(folder / rows[0][2])),
    ])
    out = tmp_path / "out"
    assert main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--no-progress"]) == 1
    printed = capsys.readouterr().out
    assert "failed pairs:" in printed and "broken: " in printed
    error = json.loads((out / "broken" / "error.json").read_text())
    assert error["status"] == "failed" and error["error"].split(":")[0].endswith("Error")
    assert not (out / "broken" / "match.json").exists()
    lines = {line["id"]: line for line in batch.read_results(out / "results.jsonl")}
    assert lines[rows[0][0]]["status"] == "ok"
    assert lines["broken"] == {"id": "broken", "status": "failed", "n_matches": None, "n_inliers": None,
                               "timings_ms": None, "error": error["error"]}

    # Run again: the finished pair is kept as it is, the failed one is tried again (and fails again).
    done = _stamps(out)
    assert main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--no-progress"]) == 1
    assert _stamps(out) == done
    assert "skipped (already complete)  1" in capsys.readouterr().out


def test_a_bad_manifest_exits_2_with_every_row_problem_and_runs_nothing(pairs_folder, tmp_path, capsys):
    folder, rows = pairs_folder
    manifest = write_csv(tmp_path / "m.csv", [("../evil", str(folder / rows[0][1]), str(folder / rows[0][2])),
                                               ("ok", "missing.png", str(folder / rows[0][2]))])
    out = tmp_path / "out"
    assert main(["batch", str(manifest), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "line 2: unsafe id '../evil'" in err and "line 3: `image_a` file not found" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.csv"]


def test_an_output_folder_symlinked_elsewhere_is_refused_before_any_work(pairs_folder, tmp_path, capsys):
    folder, rows = pairs_folder
    manifest = write_csv(tmp_path / "m.csv", [(rows[0][0], str(folder / rows[0][1]), str(folder / rows[0][2]))])
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / rows[0][0]).symlink_to(elsewhere, target_is_directory=True)
    assert main(["batch", str(manifest), "--out", str(tmp_path / "out")]) == 2
    assert "would leave the output folder" in capsys.readouterr().err
    assert list(elsewhere.iterdir()) == []


def _stamps(out: Path) -> dict[str, tuple[int, int]]:
    """(inode, mtime) of every complete match.json: a recomputed pair gets a new file by rename."""
    stamps = {}
    for folder in out.iterdir():
        if not folder.name.startswith(".") and load_match(folder) is not None:  # (not one being written)
            st = (folder / "match.json").stat()
            stamps[folder.name] = (st.st_ino, st.st_mtime_ns)
    return stamps


@pytest.mark.slow
def test_a_job_killed_midway_resumes_without_redoing_finished_pairs(tmp_path):
    rows = write_pairs(tmp_path, 8)
    manifest = write_csv(tmp_path / "m.csv", [(*row, "false") for row in rows], header="id,image_a,image_b,dense")
    out = tmp_path / "out"
    command = [sys.executable, "-m", "reglib.cli", "batch", str(manifest), "--out", str(out), "--workers", "1",
               "--no-progress"]
    log = tmp_path / "job.err"
    with log.open("wb") as err:
        job = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=err)
    deadline = time.monotonic() + 120
    while len(_stamps(out) if out.exists() else {}) < 2:
        assert job.poll() is None, log.read_text()
        assert time.monotonic() < deadline, "the job finished no pair in time"
        time.sleep(0.02)
    workers = psutil.Process(job.pid).children(recursive=True)
    os.kill(job.pid, signal.SIGKILL)
    job.wait()
    # The workers notice their job is gone and exit at once, not after their current pair.
    _, alive = psutil.wait_procs(workers, timeout=10)
    assert alive == []
    before = _stamps(out)
    assert 2 <= len(before) < len(rows), "kill the job while pairs are still to do"

    resumed = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert f"skipped (already complete)  {len(before)}" in resumed.stdout
    after = _stamps(out)
    assert sorted(after) == [row[0] for row in rows]
    assert {pair_id: after[pair_id] for pair_id in before} == before  # not computed again
    lines = batch.read_results(out / "results.jsonl")
    assert [(line["id"], line["status"]) for line in lines] == [(row[0], "ok") for row in rows]

    forced = subprocess.run([*command, "--force"], capture_output=True, text=True, timeout=300)
    assert forced.returncode == 0, forced.stderr
    redone = _stamps(out)
    assert sorted(redone) == sorted(after)
    assert all(redone[pair_id] != after[pair_id] for pair_id in after)


@pytest.mark.slow
def test_ctrl_c_is_one_line_exit_130_and_results_true_to_the_disk(tmp_path):
    rows = write_pairs(tmp_path, 8)
    manifest = write_csv(tmp_path / "m.csv", [(*row, "false") for row in rows], header="id,image_a,image_b,dense")
    out = tmp_path / "out"
    # a session of its own: SIGINT to its process group is what Ctrl-C in a terminal sends (job and workers)
    job = subprocess.Popen([sys.executable, "-m", "reglib.cli", "batch", str(manifest), "--out", str(out),
                            "--workers", "2", "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while len(_stamps(out) if out.exists() else {}) < 1:
        assert job.poll() is None, job.communicate()[1]
        assert time.monotonic() < deadline, "the job finished no pair in time"
        time.sleep(0.02)
    workers = psutil.Process(job.pid).children(recursive=True)
    os.killpg(job.pid, signal.SIGINT)
    _, err = job.communicate(timeout=60)
    assert job.returncode == 130
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("reglib batch: interrupted: "), err
    _, alive = psutil.wait_procs(workers, timeout=10)
    assert alive == []
    records = batch.read_results(out / "results.jsonl")
    on_disk = {row[0] for row in rows if load_match(out / row[0]) is not None}
    assert 1 <= len(on_disk) < len(rows), "interrupt while pairs are still to do"
    assert {r["id"] for r in records if r["status"] == "ok"} == on_disk
    assert [r["id"] for r in records] == [row[0] for row in rows]
    assert f"{len(on_disk)} of {len(rows)} pairs complete" in lines[0]


@pytest.mark.parametrize("flags, message", [
    (["--workers", "0"], "`workers` must be a positive integer, got 0"),
    (["--dask-local", "0"], "`local_workers` must be a positive integer, got 0"),
    (["--retries", "-1"], "`retries` must be a non-negative integer, got -1"),
    (["--method", "ransac"], "`method` must be one of ['l2e', 'vfc'], got 'ransac'"),
])
def test_bad_usage_exits_2(pairs_folder, tmp_path, capsys, flags, message):
    folder, rows = pairs_folder
    manifest = write_csv(tmp_path / "m.csv", [(rows[0][0], str(folder / rows[0][1]), str(folder / rows[0][2]))])
    assert main(["batch", str(manifest), "--out", str(tmp_path / "out"), *flags]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
