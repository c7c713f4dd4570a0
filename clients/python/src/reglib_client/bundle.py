"""``MatchBundle``: a match and its files in one answer (``POST /v1/match/bundle``), and saving them.

The service answers ``{"match": <the /v1/match JSON>, "files": {name: base64, ...}}`` with the files
``warped.png``, ``overlay.png``, ``flow.png``, ``flow.flo`` and, when the match has a confidence map,
``confidence.png``. :meth:`MatchBundle.save` writes them into a folder with ``match.json`` and
``transform.json``, the file names of ``reglib match --out``.
"""
from __future__ import annotations

import base64
import binascii
import copy
import json
import os
import re
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from .results import MatchResult

__all__ = ["MatchBundle", "MATCH_FILE", "TRANSFORM_FILE"]

MATCH_FILE = "match.json"
TRANSFORM_FILE = "transform.json"
# A file name the service may send: a plain name in the folder, never a path or a hidden file.
_FILE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*(\.[A-Za-z0-9]+)+")


def _files(value: Any) -> Mapping[str, bytes]:
    if not isinstance(value, dict):
        raise ValueError(f"bundle `files` must be a JSON object, got {type(value).__name__}")
    files = {}
    for name, encoded in value.items():
        if not isinstance(name, str) or not _FILE_NAME.fullmatch(name) or name in (MATCH_FILE, TRANSFORM_FILE):
            raise ValueError(f"bundle `files` has an unusable file name {name!r}")
        if not isinstance(encoded, str):
            raise ValueError(f"bundle file {name!r} must be a base64 string, got {type(encoded).__name__}")
        try:
            files[name] = base64.b64decode(encoded, validate=True)
        except binascii.Error as exc:
            raise ValueError(f"bundle file {name!r} is not valid base64: {exc}") from None
    return MappingProxyType(files)


def _write_atomic(path: Path, content: bytes) -> None:
    """Write through a temporary file in the same folder and a rename: a reader never sees half a file."""
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        with os.fdopen(handle, "wb") as out:
            out.write(content)
        os.chmod(temporary, 0o644)  # mkstemp makes 0600; saved results are meant to be shared
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


@dataclass(frozen=True, slots=True, eq=False)
class MatchBundle:
    """A match and its files, from one request (``Client.match_bundle``).

    Attributes
    ----------
    match : MatchResult
        The match, as :meth:`Client.match` gives it.
    files : Mapping[str, bytes]
        File name -> decoded bytes: ``warped.png`` (image b on image a's grid), ``overlay.png`` (a
        blended with warped b, weight ``alpha``), ``flow.png`` (the flow's colour picture), ``flow.flo``
        (the forward flow a -> b, Middlebury) and ``confidence.png`` when the match has a confidence
        map (8-bit grey, 255 = 1.0). Decode them with :func:`reglib_client.decode_png` and
        :func:`reglib_client.decode_flow`.
    match_json : Mapping[str, Any]
        The match JSON as the service sent it (what :meth:`save` writes as ``match.json``).
    """

    match: MatchResult
    files: Mapping[str, bytes]
    match_json: Mapping[str, Any]

    @classmethod
    def from_json(cls, data: Any) -> MatchBundle:
        """Read the ``/v1/match/bundle`` answer; a malformed part is a ``ValueError`` naming it."""
        if not isinstance(data, dict):
            raise ValueError(f"bundle must be a JSON object, got {type(data).__name__}")
        missing = [key for key in ("match", "files") if key not in data]
        if missing:
            raise ValueError(f"bundle is missing field(s) {missing}")
        match = MatchResult.from_json(data["match"])
        return cls(match=match, files=_files(data["files"]),
                   match_json=MappingProxyType(copy.deepcopy(data["match"])))

    def save(self, folder: str | os.PathLike[str]) -> dict[str, Path]:
        """Write every file, ``transform.json`` (the match's transform) and ``match.json`` into ``folder``.

        The folder is made if needed; each file is written atomically and ``match.json`` last, so its
        presence means the folder is complete (as with ``reglib match --out``). Existing files of the
        same names are replaced.

        Returns
        -------
        dict of str to Path
            File name -> the path written, ``match.json`` last.
        """
        out = Path(folder)
        if out.exists() and not out.is_dir():
            raise ValueError(f"`folder` exists and is not a folder: {out}")
        out.mkdir(parents=True, exist_ok=True)
        written: dict[str, Path] = {}
        for name, content in self.files.items():
            _write_atomic(out / name, content)
            written[name] = out / name
        transform = json.dumps(self.match_json["transform"]).encode("utf-8")
        _write_atomic(out / TRANSFORM_FILE, transform)
        written[TRANSFORM_FILE] = out / TRANSFORM_FILE
        _write_atomic(out / MATCH_FILE, json.dumps(dict(self.match_json)).encode("utf-8"))
        written[MATCH_FILE] = out / MATCH_FILE
        return written

    def __repr__(self) -> str:
        sizes = ", ".join(f"{name!r}: <{len(content)} bytes>" for name, content in self.files.items())
        return f"MatchBundle(match={self.match!r}, files={{{sizes}}})"
