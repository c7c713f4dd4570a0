"""What a batch job writes: the files it says (named as by ``reglib match --out``), a pair's folder only
once its files are in it, and nothing at all when the executor cannot start."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import dask
import distributed  # noqa: F401 - loads its config defaults, which a dask.config.set made before would drop on exit
import numpy as np
import pytest

from reglib import KernelWarp, batch, dense_flow
from reglib.batch._results import publish_pair, remove_leftovers
from reglib.cli import main
from reglib.errors import InputError
from reglib.io import read_flow

from .conftest import write_csv, write_pairs

DEFAULT_FILES = ["confidence.png", "match.json", "transform.json"]


@pytest.fixture(scope="module")
def one_pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, tuple[str, str, str]]:
    folder = tmp_path_factory.mktemp("one")
    return folder, write_pairs(folder, 1)[0]


def _manifest(one_pair, tmp_path: Path) -> Path:
    folder, (pair_id, image_a, image_b) = one_pair
    return write_csv(tmp_path / "m.csv", [(pair_id, str(folder / image_a), str(folder / image_b))])


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_by_default_a_pair_gets_the_match_the_transform_and_the_confidence(one_pair, tmp_path):
    manifest = _manifest(one_pair, tmp_path)
    assert main(["batch", str(manifest), "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"]) == 0
    assert _names(tmp_path / "out") == ["pair-00", "results.jsonl"]
    assert _names(tmp_path / "out" / "pair-00") == DEFAULT_FILES
    saved = json.loads((tmp_path / "out" / "pair-00" / "transform.json").read_text())
    assert saved == json.loads((tmp_path / "out" / "pair-00" / "match.json").read_text())["transform"]


@pytest.mark.slow
def test_with_every_flag_a_pair_folder_has_the_files_of_reglib_match_out(one_pair, tmp_path):
    folder, (pair_id, image_a, image_b) = one_pair
    manifest = _manifest(one_pair, tmp_path)
    out = tmp_path / "out"
    assert main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--no-progress", "--flow", "--warped",
                 "--pictures"]) == 0
    single = tmp_path / "single"
    assert main(["match", str(folder / image_a), str(folder / image_b), "--out", str(single)]) == 0
    assert _names(out / pair_id) == _names(single)
    assert _names(single) == ["confidence.png", "flow.flo", "match.json", "matches.png", "overlay.png",
                              "transform.json", "warped.png"]
    # the flow is the dense field of the pair's own transform (CONTRACTS: forward, (H_a, W_a, 2) of dx, dy)
    match = json.loads((out / pair_id / "match.json").read_text())
    flow = read_flow(out / pair_id / "flow.flo")
    want = dense_flow(KernelWarp.from_dict(match["transform"]), tuple(match["shape_a"]))
    assert flow.shape == (240, 320, 2)
    np.testing.assert_allclose(flow, want, atol=1e-4)
    np.testing.assert_allclose(flow, read_flow(single / "flow.flo"), atol=1e-3)


def test_flow_format_picks_the_flow_file_written_through_write_flow(one_pair, tmp_path, capsys):
    pair_id = one_pair[1][0]
    manifest = _manifest(one_pair, tmp_path)
    out = tmp_path / "out"
    assert main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--no-progress",
                 "--flow-format", "mha"]) == 0  # implies --flow
    assert _names(out / pair_id) == sorted([*DEFAULT_FILES, "flow.mha"])
    match = json.loads((out / pair_id / "match.json").read_text())
    want = dense_flow(KernelWarp.from_dict(match["transform"]), tuple(match["shape_a"]))
    np.testing.assert_allclose(read_flow(out / pair_id / "flow.mha"), want, atol=1e-4)
    with pytest.raises(InputError, match=r"`flow_format` must be one of \['flo', 'npy', 'mha'"):
        batch.run(manifest, tmp_path / "other", flow=True, flow_format="png")
    assert not (tmp_path / "other").exists()
    with pytest.raises(SystemExit):
        main(["batch", str(manifest), "--out", str(out), "--flow-format", "png"])
    assert "invalid choice: 'png'" in capsys.readouterr().err


def _visible_state(out: Path) -> list[str]:
    """Problems with what a reader of ``out`` sees now: a pair folder without match.json or error.json."""
    problems = []
    try:
        entries = list(out.iterdir())
    except FileNotFoundError:
        return problems
    for entry in entries:
        if entry.name.startswith(".") or entry.name == "results.jsonl":
            continue
        try:
            names = {p.name for p in entry.iterdir()}
        except FileNotFoundError:  # being replaced this instant: gone is fine
            continue
        if not names & {"match.json", "error.json"}:
            problems.append(f"{entry.name}: {sorted(names)}")
    return problems


@pytest.mark.slow
def test_a_pair_folder_appears_only_with_its_files(tmp_path):
    rows = write_pairs(tmp_path, 4)
    manifest = write_csv(tmp_path / "m.csv", [(*row, "false") for row in rows], header="id,image_a,image_b,dense")
    out = tmp_path / "out"
    log = tmp_path / "job.err"
    with log.open("wb") as err:
        job = subprocess.Popen([sys.executable, "-m", "reglib.cli", "batch", str(manifest), "--out", str(out),
                                "--workers", "1", "--no-progress", "--flow"], stdout=subprocess.DEVNULL, stderr=err)
    seen: list[str] = []
    deadline = time.monotonic() + 300
    while job.poll() is None:
        seen += _visible_state(out)
        assert time.monotonic() < deadline, "the job did not finish in time"
        time.sleep(0.002)
    assert job.returncode == 0, log.read_text()
    assert seen == []
    assert _names(out) == sorted([row[0] for row in rows] + ["results.jsonl"])  # no hidden folder left
    for row in rows:
        has_map = json.loads((out / row[0] / "match.json").read_text())["confidence"] is not None
        assert _names(out / row[0]) == ["confidence.png"] * has_map + ["flow.flo", "match.json", "transform.json"]


def test_publish_pair_replaces_a_folder_whole_or_not_at_all(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    publish_pair(out, "p1", lambda folder: (folder / "error.json").write_text("{}"))
    assert _names(out / "p1") == ["error.json"]
    publish_pair(out, "p1", lambda folder: (folder / "match.json").write_text("{}"))
    assert _names(out) == ["p1"] and _names(out / "p1") == ["match.json"]  # no error.json beside the match

    def half_then_fail(folder: Path) -> None:
        (folder / "transform.json").write_text("{}")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        publish_pair(out, "p1", half_then_fail)
    assert _names(out) == ["p1"] and _names(out / "p1") == ["match.json"]
    with pytest.raises(OSError):
        publish_pair(out, "p2", half_then_fail)
    assert _names(out) == ["p1"]


def test_remove_leftovers_removes_only_the_hidden_folders_of_the_given_ids(tmp_path):
    keep = [".p1.0123456789ab.partial", ".other.0123456789ab.old", ".p1.notes", "p1"]
    drop = [".p1.0123456789ab.partial", ".p1.fedcba987654.old", ".p.2.aaaaaaaaaaaa.partial"]
    for name in set(keep + drop):
        (tmp_path / name).mkdir()
    remove_leftovers(tmp_path, ["p1", "p.2"])
    assert _names(tmp_path) == sorted([".other.0123456789ab.old", ".p1.notes", "p1"])


def test_a_missing_dask_leaves_nothing_behind(one_pair, tmp_path, capsys, monkeypatch):
    manifest = _manifest(one_pair, tmp_path)
    monkeypatch.setitem(sys.modules, "distributed", None)  # as on a machine without reglib[dask]
    assert main(["batch", str(manifest), "--out", str(tmp_path / "out"), "--dask-local", "1"]) == 2
    assert "reglib batch: error: the Dask executor needs dask[distributed]" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_dask_cluster_that_cannot_start_leaves_nothing_behind(one_pair, tmp_path, capsys):
    manifest = _manifest(one_pair, tmp_path)
    out = tmp_path / "out"
    # Each worker must import a module that does not exist: the LocalCluster's nanny fails to start.
    with dask.config.set({"distributed.worker.preload": ["reglib_no_such_module"]}):
        assert main(["batch", str(manifest), "--out", str(out), "--dask-local", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "reglib batch: error: the dask LocalCluster x 1 could not start: RuntimeError" in err
    assert not out.exists()


def test_a_failed_start_keeps_an_earlier_run_as_it_was(one_pair, tmp_path, capsys):
    manifest = _manifest(one_pair, tmp_path)
    out = tmp_path / "out"
    assert main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    before = {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        assert main(["batch", str(manifest), "--out", str(out), "--force", "--scheduler", "tcp://127.0.0.1:9",
                     "--no-progress"]) == 2
    assert "the dask scheduler tcp://127.0.0.1:9 could not start: OSError" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
