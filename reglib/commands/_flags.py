"""Command-line flags derived from declared options (:class:`reglib.options.OptionSpec`).

Each option becomes ``--name-with-dashes``; booleans get ``--name`` / ``--no-name``. Values are
collected as given (text) and parsed by the library's own request parser, so a flag's bounds and
messages are the library's.
"""
from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..options import OptionSpec

__all__ = ["add_option_flags", "given_options", "json_flag", "out_file", "out_folder"]

_DEST = "opt__"
_NO_LIMIT = 2.0**53  # a bound this large is an implementation limit, not advice: left out of the help


def add_option_flags(parser: argparse.ArgumentParser, specs: Iterable[OptionSpec], *,
                     aliases: dict[str, list[str]] | None = None) -> None:
    """Add one flag per option to ``parser`` (absent flags leave the option at its default)."""
    group = parser.add_argument_group("match options (as in reglib.MatchOptions and the service's form)")
    for spec in specs:
        flags = [f"--{spec.name.replace('_', '-')}", *(aliases or {}).get(spec.name, [])]
        bounds = _bounds(spec)
        help_text = f"{spec.doc} (default {spec.default!r}{bounds})"
        if spec.kind == "bool":
            group.add_argument(*flags, dest=_DEST + spec.name, action=argparse.BooleanOptionalAction, default=None,
                               help=help_text)
        elif spec.kind == "choice":
            group.add_argument(*flags, dest=_DEST + spec.name, choices=spec.choices, default=None, help=help_text)
        else:
            metavar = {"int": "N", "float": "X", "json": "JSON"}[spec.kind]
            group.add_argument(*flags, dest=_DEST + spec.name, metavar=metavar, default=None, help=help_text)


def given_options(args: argparse.Namespace) -> dict[str, Any]:
    """The option flags that were given, by option name (values as typed)."""
    return {key[len(_DEST):]: value for key, value in vars(args).items()
            if key.startswith(_DEST) and value is not None}


def json_flag(text: str | None, flag: str) -> Any:
    """The JSON value of a flag such as ``--options`` (None when not given); bad JSON is an ``InputError``."""
    import json

    from ..errors import InputError

    if not text:
        return None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{flag} is not valid JSON: {exc}") from None


def read_transform_file(path: Path) -> tuple[Any, dict[str, Any]]:
    """A transform JSON file, or a match.json: its ``transform`` object and the match's ``shape_a`` / ``shape_b``.

    Returns the transform's JSON value (checked by the caller, e.g. ``KernelWarp.from_dict``) and
    ``{"shape_a": ..., "shape_b": ...}`` as the file gives them (None for a bare transform).

    Raises
    ------
    InputError
        A missing file or one that is not JSON.
    """
    import json

    from ..errors import InputError

    if not path.is_file():
        raise InputError(f"no such transform file: {path}")
    try:
        body = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path.name}: not JSON: {exc}") from None
    shapes: dict[str, Any] = {"shape_a": None, "shape_b": None}
    if isinstance(body, dict) and isinstance(body.get("transform"), dict):  # a match.json
        shapes = {k: body.get(k) for k in shapes}
        body = body["transform"]
    return body, shapes


def out_file(path: Path) -> Path:
    """``--out`` as a file to write: its folder must exist (it is never created) and it must not be a folder.

    Raises
    ------
    InputError
        In the CLI's own words: ``--out x.json: the folder /missing does not exist``.
    """
    from ..errors import InputError

    folder = path.parent
    if path.is_dir():
        raise InputError(f"--out {path} is a folder; give a file name")
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise InputError(f"--out {path}: the folder {folder} {what} (create it first; reglib does not create "
                         "parent folders)")
    return path


def out_folder(path: Path) -> Path:
    """``--out`` as a folder of results: it may exist (as a folder) or be created, but its parent must exist.

    Raises
    ------
    InputError
        ``--out x exists and is not a folder``, or a missing parent folder, named.
    """
    from ..errors import InputError

    if path.exists() and not path.is_dir():
        raise InputError(f"--out {path} exists and is not a folder; give a folder for the results")
    if not path.exists() and not path.parent.is_dir():
        raise InputError(f"--out {path}: the folder {path.parent} does not exist (only --out itself is created, "
                         "never its parents)")
    return path


def _number(value: float, kind: str) -> str:
    """A bound as the user would type it: integers in full (1000000, not 1e+06), floats short."""
    if kind == "int" or float(value).is_integer():
        return str(int(value))
    return f"{value:g}"


def _bounds(spec: OptionSpec) -> str:
    parts = []
    if spec.low is not None:
        parts.append(f"{'>' if spec.low_open else '>='} {_number(spec.low, spec.kind)}")
    if spec.high is not None and spec.high < _NO_LIMIT:
        parts.append(f"{'<' if spec.high_open else '<='} {_number(spec.high, spec.kind)}")
    return ("; " + ", ".join(parts)) if parts else ""
