"""``reglib serve [--host H] [--port P] [--workers N]``: run the HTTP service under uvicorn.

One uvicorn process (so ``/metrics`` sees every request) whose compute pool has N supervised worker
processes. Other limits come from ``REGLIB_*`` environment variables (see the README).

Stopping: the first SIGTERM (or SIGINT) starts the drain (:mod:`service.lifecycle`): new requests
and ``/readyz`` get 503 at once, the requests in flight get up to ``REGLIB_SHUTDOWN_GRACE_S`` to
finish, then the server closes its socket, stops the workers and the command exits 0. A second
signal during the drain stops at once (and the process ends by that signal). Log lines are text,
or one JSON object a line with ``REGLIB_LOG_FORMAT=json`` (:mod:`service.logs`).
"""
from __future__ import annotations

import argparse
import asyncio
import errno
import socket
from types import FrameType
from typing import Any

NAME = "serve"
HELP = "run the HTTP service (needs the [service] extra)"

_WIND_DOWN_S = 5  # after the drain: uvicorn's own wait for connections to close


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    parser.add_argument("--workers", type=int, default=None,
                        help="compute processes (default: REGLIB_WORKERS, else the CPUs available)")
    parser.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])


def _check_port(host: str, port: int) -> None:
    """Bind ``host:port`` as uvicorn will, and let it go: a port in use (or not ours to take) is one line and exit 2
    here, before the worker pool starts, not uvicorn's log lines and exit 3 after it.

    Raises
    ------
    InputError
        The address cannot be bound; the message names it and why.
    """
    from ..errors import InputError

    family = socket.AF_INET6 if ":" in host else socket.AF_INET  # (uvicorn's choice of family for a host)
    try:
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            why = "the port is in use (another server?); choose another with --port"
        elif exc.errno == errno.EACCES:
            why = "permission denied (ports below 1024 need privileges); choose another with --port"
        else:
            why = exc.strerror or str(exc)
        raise InputError(f"cannot listen on {host}:{port}: {why}") from None


def _draining_server(uvicorn: Any, config: Any, app: Any) -> Any:
    """A ``uvicorn.Server`` whose first stop signal drains the app instead of closing at once."""

    class DrainingServer(uvicorn.Server):  # type: ignore[misc]  # uvicorn is passed in (imported lazily): Any
        _loop: asyncio.AbstractEventLoop | None = None
        _drain: asyncio.Task[None] | None = None

        async def serve(self, sockets: Any = None) -> None:
            self._loop = asyncio.get_running_loop()
            await super().serve(sockets)

        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            stopping: bool = self.should_exit  # type: ignore[has-type]  # (uvicorn's attribute)
            if self._drain is None and self.started and not stopping and self._loop is not None:
                self._loop.call_soon_threadsafe(self._start_drain)
                return
            if self._drain is None and not self.started:  # still starting: stop, as cleanly as uvicorn can
                self.should_exit = True
                return
            super().handle_exit(sig, frame)  # a second signal: stop now

        def _start_drain(self) -> None:
            if self._drain is None:
                self._drain = asyncio.get_running_loop().create_task(self._drain_then_exit())

        async def _drain_then_exit(self) -> None:
            try:
                await app.state.lifecycle.drain()
            finally:
                self.should_exit = True

    return DrainingServer(config)


def run(args: argparse.Namespace) -> int:
    try:
        from service.config import Settings, SettingsError
    except ImportError as exc:
        raise SystemExit(f"reglib serve: the service needs the [service] extra "
                         f"(pip install 'reglib[service]'): {exc}") from None
    # The settings first, before the heavy imports: a bad REGLIB_* variable is one line naming it
    # (a SettingsError is an InputError: the CLI prints it and exits 2), at once.
    try:
        settings = Settings() if args.workers is None else Settings(workers=args.workers)
    except SettingsError as exc:  # the keyword `workers` is the --workers flag here
        raise SettingsError(p.replace("`workers` ", "`--workers` ", 1) for p in exc.problems) from None
    _check_port(args.host, args.port)
    try:
        import uvicorn

        from service.app import create_app
        from service.connections import guarded_protocol
        from service.logs import log_config
    except ImportError as exc:
        raise SystemExit(f"reglib serve: the service needs the [service] extra "
                         f"(pip install 'reglib[service]'): {exc}") from None
    app = create_app(settings)
    config = uvicorn.Config(app, host=args.host, port=args.port, log_level=args.log_level,
                            log_config=log_config(settings.log_format, args.log_level), access_log=False,
                            timeout_graceful_shutdown=_WIND_DOWN_S, http=guarded_protocol(settings))
    server = _draining_server(uvicorn, config, app)
    server.run()  # a second signal has uvicorn end the process by that signal before this returns
    return 0
