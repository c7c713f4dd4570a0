"""What a batch job leaves on disk, and how a resumed job reads it back.

``OUT/<id>/match.json`` (written last by :func:`reglib.outputs.save_match`) marks a finished pair;
``OUT/<id>/error.json`` a failed one. A pair's folder is written whole in a hidden folder beside it
and then moved into place (:func:`publish_pair`): ``OUT/<id>/`` never exists empty or half-written.
``OUT/results.jsonl`` holds one summary line per pair (``id``, ``status``, ``n_matches``,
``n_inliers``, ``timings_ms``, ``error``, and for a pair that ran, ``converged`` and ``reason``);
lines are appended as pairs finish so the file can be followed, and the whole file is rebuilt from
the per-pair files at the start and the end of every run: it is a view, never the record a resumed job trusts.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io import write_bytes_atomic
from ..outputs import MATCH_FILE

__all__ = ["MATCH_FILE", "ERROR_FILE", "RESULTS_FILE", "pair_dir", "publish_pair", "remove_leftovers",
           "write_json_atomic", "load_match", "pair_record", "rebuild_results", "read_results", "format_summary"]

ERROR_FILE = "error.json"
RESULTS_FILE = "results.jsonl"
_MATCH_KEYS = ("n_matches", "n_inliers", "converged", "reason", "timings_ms")
# Hidden folders beside OUT/<id>: ".<id>.<hex>.partial" (being written) and ".<id>.<hex>.old" (being
# replaced). Ids start with a letter or digit (manifest.ID_PATTERN), so no id is ever one of these.
_LEFTOVER = re.compile(r"\.(?P<id>[A-Za-z0-9][A-Za-z0-9._-]*)\.[0-9a-f]{12}\.(partial|old)")


def pair_dir(out: Path, pair_id: str) -> Path:
    """``out/<pair_id>``, refusing any id or existing symlink that would put output outside ``out``."""
    root = out.resolve()
    target = root / pair_id
    if target.is_symlink() or target.resolve().parent != root:
        raise InputError(f"output for id {pair_id!r} would leave the output folder {root}")
    return target


def _hidden(out: Path, pair_id: str, kind: str) -> Path:
    return out / f".{pair_id}.{uuid.uuid4().hex[:12]}.{kind}"


def publish_pair(out: Path, pair_id: str, write: Callable[[Path], object]) -> Path:
    """Make ``out/<pair_id>/`` appear whole: ``write(folder)`` fills a hidden folder, which is then renamed.

    An existing ``out/<pair_id>/`` is replaced (moved aside, then deleted). When ``write`` raises, its
    hidden folder is removed and the pair's folder is left as it was.

    Returns
    -------
    Path
        ``out/<pair_id>``.
    """
    final = pair_dir(out, pair_id)
    staging = _hidden(out, pair_id, "partial")
    staging.mkdir(parents=True)
    try:
        write(staging)
        if final.exists():
            old = _hidden(out, pair_id, "old")
            os.rename(final, old)
            os.rename(staging, final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return final


def remove_leftovers(out: Path, ids: Iterable[str]) -> None:
    """Delete the hidden folders a killed job left beside the folders of ``ids`` (see :func:`publish_pair`)."""
    wanted = set(ids)
    if not out.is_dir():
        return
    for entry in out.iterdir():
        found = _LEFTOVER.fullmatch(entry.name)
        if found and found["id"] in wanted and entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)


def write_json_atomic(path: Path, body: Any) -> None:
    """Write ``body`` as JSON to ``path`` through a temporary file and a rename: all or nothing."""
    write_bytes_atomic(path, json.dumps(body).encode("utf-8"))


def _load_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def load_match(folder: Path) -> dict[str, Any] | None:
    """The pair's match JSON if ``folder/match.json`` is complete, valid JSON with the summary keys; else None."""
    body = _load_json(folder / MATCH_FILE)
    if isinstance(body, dict) and all(key in body for key in _MATCH_KEYS):
        return body
    return None


def pair_record(out: Path, pair_id: str) -> dict[str, Any]:
    """The ``results.jsonl`` line of one pair, from its files: ok, failed, or missing (never run)."""
    folder = out / pair_id
    match = load_match(folder)
    if match is not None:
        return {"id": pair_id, "status": "ok", "n_matches": match["n_matches"], "n_inliers": match["n_inliers"],
                "converged": match["converged"], "reason": match["reason"], "timings_ms": match["timings_ms"],
                "error": None}
    error = _load_json(folder / ERROR_FILE)
    message = error.get("error") if isinstance(error, dict) else None
    return {"id": pair_id, "status": "failed" if message else "missing", "n_matches": None, "n_inliers": None,
            "timings_ms": None, "error": message or "not run"}


def rebuild_results(out: Path, ids: Iterable[str]) -> list[dict[str, Any]]:
    """Rewrite ``out/results.jsonl`` atomically from the per-pair files, one line per id in order."""
    records = [pair_record(out, pair_id) for pair_id in ids]
    write_bytes_atomic(out / RESULTS_FILE, "".join(json.dumps(record) + "\n" for record in records).encode("utf-8"))
    return records


def read_results(path: str | Path) -> list[dict[str, Any]]:
    """Read a ``results.jsonl``; a truncated last line (a job killed while appending it) is ignored.

    Raises
    ------
    InputError
        When a line other than an unterminated last one is not a JSON object.
    """
    text = Path(path).read_text(encoding="utf-8")
    lines = text.split("\n")
    records = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except ValueError:
            if number == len(lines):  # no newline after it: the write was cut short
                break
            raise InputError(f"{path}: line {number} is not valid JSON") from None
        if not isinstance(record, dict):
            raise InputError(f"{path}: line {number} is not a JSON object")
        records.append(record)
    return records


def format_summary(records: Sequence[Mapping[str, Any]], *, skipped: int, seconds: float, executor: str,
                   max_failures: int = 20) -> str:
    """The table printed at the end of a job: counts, rate, and the first failures with their errors."""
    ran = [record for record in records if record["status"] == "ok"]
    unconverged = [record for record in ran if not record.get("converged", True)]
    failed = [record for record in records if record["status"] == "failed"]
    missing = len(records) - len(ran) - len(failed)
    computed = len(records) - skipped - missing
    rate = computed / seconds if seconds > 0 else 0.0
    # a pair that ran but did not converge is no error, nor an answer to use: counted apart, with why
    reasons = Counter(str(record.get("reason")) for record in unconverged)
    why = f" ({', '.join(f'{reason}: {n}' for reason, n in sorted(reasons.items()))})" if reasons else ""
    rows = [("pairs", str(len(records))), ("ok", str(len(ran) - len(unconverged))),
            ("not converged", f"{len(unconverged)}{why}"), ("failed", str(len(failed))),
            ("skipped (already complete)", str(skipped))]
    if missing:
        rows.append(("not run", str(missing)))
    rows += [("executor", executor), ("time", f"{seconds:.1f} s"), ("rate", f"{rate:.2f} pairs/s")]
    width = max(len(name) for name, _ in rows)
    lines = [f"{name:<{width}}  {value}" for name, value in rows]
    if failed:
        lines.append("")
        lines.append("failed pairs:")
        for record in failed[:max_failures]:
            lines.append(f"  {record['id']}: {record['error']}")
        if len(failed) > max_failures:
            lines.append(f"  ... and {len(failed) - max_failures} more (see {RESULTS_FILE})")
    return "\n".join(lines)
