"""Command-line flags derived from declared options (:class:`reglib.options.OptionSpec`).

Each option becomes ``--name-with-dashes``; booleans get ``--name`` / ``--no-name``. Values are
collected as given (text) and parsed by the library's own request parser, so a flag's bounds and
messages are the library's.
"""
from __future__ import annotations

import argparse
from collections.abc import Iterable
from typing import Any

from ..options import OptionSpec

__all__ = ["add_option_flags", "given_options", "json_flag"]

_DEST = "opt__"


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


def _bounds(spec: OptionSpec) -> str:
    parts = []
    if spec.low is not None:
        parts.append(f"{'>' if spec.low_open else '>='} {spec.low:g}")
    if spec.high is not None:
        parts.append(f"{'<' if spec.high_open else '<='} {spec.high:g}")
    return ("; " + ", ".join(parts)) if parts else ""
