"""The ``reglib`` command line.

Each sub-command lives in its own module of :mod:`reglib.commands` and defines ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; heavy imports (the service, Dask) happen inside
``run`` only, so ``reglib --help`` stays fast and needs no optional extra.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from . import commands
from .errors import ReglibError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="reglib", description="Robust correspondence and non-rigid registration.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        cmd = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``reglib`` command; returns the process exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
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
