"""``reglib serve [--host H] [--port P] [--workers N]``: run the HTTP service under uvicorn.

One uvicorn process (so ``/metrics`` sees every request) whose compute pool has N worker
processes. Other limits come from ``REGLIB_*`` environment variables (see the README).
"""
from __future__ import annotations

import argparse

NAME = "serve"
HELP = "run the HTTP service (needs the [service] extra)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    parser.add_argument("--workers", type=int, default=None,
                        help="compute processes (default: REGLIB_WORKERS, else the CPUs available)")
    parser.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])


def run(args: argparse.Namespace) -> int:
    try:
        import uvicorn

        from service.app import create_app
        from service.config import Settings
    except ImportError as exc:
        raise SystemExit(f"reglib serve: the service needs the [service] extra "
                         f"(pip install 'reglib[service]'): {exc}") from None
    if args.workers is not None and args.workers < 1:
        raise SystemExit("reglib serve: --workers must be >= 1")
    settings = Settings() if args.workers is None else Settings(workers=args.workers)
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level=args.log_level,
                timeout_graceful_shutdown=10)
    return 0
