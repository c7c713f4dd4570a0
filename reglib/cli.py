"""The ``reglib`` command line.

Each sub-command lives in its own module of :mod:`reglib.commands` and defines ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports (the service, Dask) happen inside
``run`` only, so ``reglib --help`` stays fast and needs no optional extra.

A misspelled sub-command or flag is answered with the nearest valid ones (``did you mean --ratio?``)
under the usage of the sub-command it was given to; exit status 2, as for every usage error.
"""
from __future__ import annotations

import argparse
import difflib
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from typing import NoReturn

from . import commands
from ._validation import is_number
from .errors import ReglibError


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors name the nearest valid sub-command or flag."""

    given: Sequence[str] = ()  # the command line being parsed (set by :func:`main`)

    def error(self, message: str) -> NoReturn:
        super().error(message + suggestions(self, self.given))


def suggestions(parser: argparse.ArgumentParser, argv: Sequence[str]) -> str:
    """``"; did you mean ...?"`` hints for the words of ``argv`` that ``parser`` does not know ("" for none).

    A word that starts with ``-`` and is none of the parser's flags (``--ratoi``, ``--ratoi=3``) is
    matched against its flags; for the top-level parser, the first other word is matched against
    the sub-commands. The matching is :func:`difflib.get_close_matches` (Python 3.11's argparse
    suggests nothing itself).
    """
    flags = [s for action in parser._actions for s in action.option_strings]
    commands_action = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    hints = []
    for word in argv:
        if word == "--":
            break
        if word.startswith("-") and len(word) > 1 and not is_number(word):
            flag = word.split("=", 1)[0]
            if flag in flags or any(f.startswith(flag) for f in flags if flag.startswith("--")):
                continue  # known, or an abbreviation argparse accepts
            close = difflib.get_close_matches(flag, flags, n=2, cutoff=0.7)
            if close:
                hints.append(f"{flag}: did you mean {' or '.join(close)}?")
        elif commands_action is not None:  # the first positional word names the sub-command
            names = list(commands_action.choices)
            if word not in names:
                close = difflib.get_close_matches(word, names, n=3, cutoff=0.5)
                if close:
                    hints.append(f"{word!r}: did you mean {' or '.join(repr(c) for c in close)}?")
            break
    return ("; " + "; ".join(hints)) if hints else ""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="reglib", description="Robust correspondence and non-rigid registration.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        cmd = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``reglib`` command; returns the process exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    by_name = _subcommands(parser)
    for p in (parser, *by_name.values()):
        if isinstance(p, _Parser):
            p.given = argv
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # said by the sub-command's parser, under its usage, with the nearest flags
        by_name[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return int(args._run(args) or 0)
    except ReglibError as exc:  # a named problem with the user's input: one line, no traceback
        print(f"reglib {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        message = f"reglib {args.command}: error: {exc.strerror or exc}: {exc.filename or ''}"
        print(message.rstrip(": "), file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
