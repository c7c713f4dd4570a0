"""The per-pair files and results.jsonl: what a resumed job trusts, and what it ignores."""
from __future__ import annotations

import json
import re

import pytest

from reglib.batch import read_results
from reglib.batch._results import (
    format_summary,
    load_match,
    pair_dir,
    pair_record,
    rebuild_results,
    write_json_atomic,
)
from reglib.errors import InputError

MATCH = {"n_matches": 10, "n_inliers": 7, "converged": False, "reason": "too_few_inliers",
         "timings_ms": {"features": 1.5}, "src": [], "dst": []}


def test_read_results_ignores_a_truncated_last_line(tmp_path):
    path = tmp_path / "results.jsonl"
    path.write_text('{"id": "a", "status": "ok"}\n{"id": "b", "sta')
    assert read_results(path) == [{"id": "a", "status": "ok"}]


def test_read_results_rejects_a_bad_line_before_the_last(tmp_path):
    path = tmp_path / "results.jsonl"
    path.write_text('{"id": "a", "sta\n{"id": "b", "status": "ok"}\n')
    with pytest.raises(InputError, match="line 1 is not valid JSON"):
        read_results(path)


def test_load_match_needs_complete_json_with_the_summary_keys(tmp_path):
    assert load_match(tmp_path) is None  # no file
    (tmp_path / "match.json").write_text(json.dumps(MATCH)[:-5])  # cut short
    assert load_match(tmp_path) is None
    (tmp_path / "match.json").write_text(json.dumps({"n_matches": 3}))  # not a match result
    assert load_match(tmp_path) is None
    write_json_atomic(tmp_path / "match.json", MATCH)
    assert load_match(tmp_path) == MATCH
    assert [p.name for p in tmp_path.iterdir()] == ["match.json"]  # no temporary file left behind


def test_rebuild_results_writes_one_line_per_id_from_the_pair_files(tmp_path):
    (tmp_path / "good").mkdir()
    write_json_atomic(tmp_path / "good" / "match.json", MATCH)
    (tmp_path / "bad").mkdir()
    write_json_atomic(tmp_path / "bad" / "error.json", {"id": "bad", "status": "failed", "error": "InputError: x"})
    (tmp_path / "results.jsonl").write_text('{"id": "stale"}\n{"id": "tru')
    records = rebuild_results(tmp_path, ["good", "bad", "never"])
    assert read_results(tmp_path / "results.jsonl") == records
    assert [(r["id"], r["status"]) for r in records] == [("good", "ok"), ("bad", "failed"), ("never", "missing")]
    assert records[0] == {"id": "good", "status": "ok", "n_matches": 10, "n_inliers": 7, "converged": False,
                          "reason": "too_few_inliers", "timings_ms": {"features": 1.5}, "error": None}
    assert records[1]["error"] == "InputError: x"
    assert pair_record(tmp_path, "never")["error"] == "not run"


def test_pair_dir_refuses_a_symlink_out_of_the_folder(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (out / "p1").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(InputError, match="would leave the output folder"):
        pair_dir(out, "p1")
    with pytest.raises(InputError, match="would leave the output folder"):
        pair_dir(out, "../p2")
    assert pair_dir(out, "p2") == out.resolve() / "p2"


def test_the_summary_counts_converged_unconverged_and_failed_apart():
    rows = [{"id": "a", "status": "ok", "converged": True, "reason": None},
            {"id": "b", "status": "ok", "converged": False, "reason": "too_few_matches"},
            {"id": "c", "status": "ok", "converged": False, "reason": "too_few_matches"},
            {"id": "d", "status": "failed", "error": "InputError: x"}]
    table = format_summary(rows, skipped=0, seconds=1.0, executor="local")
    counts = {name.strip(): value.strip() for name, value in
              (re.split(r"\s{2,}", line, maxsplit=1) for line in table.splitlines() if "  " in line)}
    assert counts["ok"] == "1" and counts["failed"] == "1" and counts["pairs"] == "4"
    assert counts["not converged"] == "2 (too_few_matches: 2)"
