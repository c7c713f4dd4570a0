"""Batch manifests: which image pairs to match, read and checked in full before any work starts.

A manifest is a CSV file with a header row, or a JSON-lines file (``.jsonl`` / ``.ndjson``) of
objects. Each row names a pair: ``id``, ``image_a``, ``image_b``; any further column (key) is a
per-row option of :func:`reglib.match_images`: ``features``, ``method``, ``seed`` or a field of
:class:`reglib.MatchOptions`. An empty CSV cell leaves that option at the job's default.

Relative image paths are taken from the manifest's folder. An ``id`` names the pair's output folder
``OUT/<id>/``, so it must be a plain name: letters, digits, ``.``, ``_`` and ``-``, starting with a
letter or digit (no ``/``, no ``..``, not absolute).
"""
from __future__ import annotations

import csv
import dataclasses
import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..errors import InputError

__all__ = ["ManifestError", "PairSpec", "read_manifest", "PAIR_KEYS", "ID_PATTERN"]

PAIR_KEYS = ("id", "image_a", "image_b")
ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")
RESERVED_IDS = frozenset({"results.jsonl"})  # files the job itself writes at the top of OUT
_JSON_LINES = (".jsonl", ".ndjson")


class ManifestError(InputError):
    """A manifest that cannot be run; ``problems`` holds one message per bad row."""

    def __init__(self, path: Path, problems: list[str]):
        self.path = path
        self.problems = problems
        shown = problems[:50]
        more = f"\n  ... and {len(problems) - len(shown)} more" if len(problems) > len(shown) else ""
        super().__init__(f"{path}: {len(problems)} problem(s):\n  " + "\n  ".join(shown) + more)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class PairSpec:
    """One row of a manifest: a pair of image files and the options to match them with.

    ``image_a`` and ``image_b`` are absolute paths (workers on a cluster must be able to read them);
    ``options`` holds only the row's own options, already checked.
    """

    id: str
    image_a: str
    image_b: str
    options: Mapping[str, Any] = dataclasses.field(default_factory=dict)


def check_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """Check a row's (or the job's) options with :meth:`reglib.MatchRequest.from_fields` and return
    them as JSON values (CSV text read as the option's kind says).

    Raises
    ------
    InputError
        For an unknown name or a bad value; the message names the option.
    """
    from ..matching import MatchRequest

    fields = MatchRequest.from_fields(options, what="").to_fields()
    return {name: fields[name] for name in options}


def _option_problems(options: Mapping[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """A row's options checked (:func:`check_options`) and every problem among them: the unknown names, then
    each known option's bad value on its own, so that one bad name does not hide a bad value beside it."""
    from ..matching import match_request_specs

    names = {spec.name for spec in match_request_specs()}
    unknown = {k: v for k, v in options.items() if k not in names}
    known = {k: v for k, v in options.items() if k in names}
    problems = []
    for part in ([unknown] if unknown else []) + [{k: v} for k, v in known.items()]:
        try:
            check_options(part)
        except InputError as exc:
            problems.append(str(exc))
    if problems:
        return {}, problems
    try:  # each value is good alone; now together (the estimator fields against `method`)
        return check_options(known), []
    except InputError as exc:
        return {}, [str(exc)]


def _read_rows(path: Path) -> list[tuple[int, Any]]:
    """(line number, raw row) for every data row; a row that is not an object becomes a message string."""
    text = path.read_text(encoding="utf-8-sig")
    rows: list[tuple[int, Any]] = []
    if path.suffix.lower() in _JSON_LINES:
        for number, line in enumerate(text.splitlines(), start=1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError as exc:
                rows.append((number, f"not valid JSON: {exc.msg}"))
                continue
            rows.append((number, row if isinstance(row, dict) else f"expected a JSON object, got {type(row).__name__}"))
        return rows
    reader = csv.reader(text.splitlines())
    header = next(reader, None)
    if header is None:
        return rows
    header = [name.strip() for name in header]
    missing = [key for key in PAIR_KEYS if key not in header]
    if missing:
        raise ManifestError(path, [f"line 1: the header must name columns {list(PAIR_KEYS)}; missing {missing}"])
    dup = sorted({name for name in header if header.count(name) > 1})
    if dup:
        raise ManifestError(path, [f"line 1: column(s) {dup} appear more than once"])
    for cells in reader:
        number = reader.line_num
        if not any(cell.strip() for cell in cells):
            continue
        if len(cells) != len(header):
            rows.append((number, f"expected {len(header)} cells like the header, got {len(cells)}"))
            continue
        row = {name: cell.strip() for name, cell in zip(header, cells, strict=True) if cell.strip() != ""}
        rows.append((number, row))
    return rows


def _check_id(value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise InputError(f"`id` must be a non-empty string, got {value!r}")
    if not ID_PATTERN.fullmatch(value) or value in (".", "..") or value.lower() in RESERVED_IDS:
        raise InputError(
            f"unsafe id {value!r}: an id names the folder OUT/<id>, so it must be 1-128 letters, digits, "
            "'.', '_' or '-', starting with a letter or digit (no '/', no '..', not absolute)"
        )
    return value


def _check_image(value: Any, key: str, folder: Path) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"`{key}` must be a file path, got {value!r}")
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = folder / path
    if not path.is_file():
        raise InputError(f"`{key}` file not found: {path}")
    return str(path.resolve())


def read_manifest(path: str | Path) -> list[PairSpec]:
    """Read and check a whole manifest; return its pairs in file order.

    Parameters
    ----------
    path : str or Path
        A CSV file with a header (``id,image_a,image_b[,option...]``) or a JSON-lines file
        (``.jsonl`` / ``.ndjson``) of objects with the same keys.

    Returns
    -------
    list of PairSpec
        Image paths absolute, options checked.

    Raises
    ------
    ManifestError
        Listing every bad row by line number: missing keys, missing image files, duplicate or
        unsafe ids, unknown options or bad option values. Nothing runs on a bad manifest.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"`manifest` file not found: {path}")
    folder = path.resolve().parent
    problems: list[str] = []
    pairs: list[PairSpec] = []
    seen: dict[str, int] = {}
    for number, row in _read_rows(path):
        if isinstance(row, str):
            problems.append(f"line {number}: {row}")
            continue
        missing = [key for key in PAIR_KEYS if key not in row]
        if missing:
            problems.append(f"line {number}: missing {missing}")
            continue
        row_problems = []
        values: dict[str, str] = {}
        for key, check in (("id", lambda v: _check_id(v)),
                           ("image_a", lambda v: _check_image(v, "image_a", folder)),
                           ("image_b", lambda v: _check_image(v, "image_b", folder))):
            try:
                values[key] = check(row[key])
            except InputError as exc:
                row_problems.append(str(exc))
        options = {name: value for name, value in row.items() if name not in PAIR_KEYS}
        options, option_problems = _option_problems(options)
        row_problems.extend(option_problems)
        if "id" in values:
            # Ids name folders, and some file systems ignore case: "A" and "a" would share one.
            first = seen.setdefault(values["id"].casefold(), number)
            if first != number:
                row_problems.append(f"duplicate id {values['id']!r} (first on line {first})")
        if row_problems:
            problems.extend(f"line {number}: {message}" for message in row_problems)
            continue
        pairs.append(PairSpec(id=values["id"], image_a=values["image_a"], image_b=values["image_b"], options=options))
    if problems:
        raise ManifestError(path, problems)
    if not pairs:
        raise ManifestError(path, ["no pairs: the manifest has no data rows"])
    return pairs
