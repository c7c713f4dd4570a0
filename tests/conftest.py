"""What every part of the suite shares: a free port on 127.0.0.1 and a real server process on it."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]  # the repository (``service`` imports from here)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _environment(changes: dict[str, str | None] | None) -> dict[str, str]:
    merged: dict[str, str | None] = {**os.environ, **(changes or {})}
    return {k: v for k, v in merged.items() if v is not None}


class LiveServer:
    """A server process on 127.0.0.1 (``python -m ARGS``, ``{port}`` filled in); stopped by :meth:`stop`
    (SIGTERM, then SIGKILL), its stderr and stdout kept in a file (a full pipe would block it). ``env``
    is laid over this process's environment; a None value removes that variable."""

    def __init__(self, args: Sequence[str], env: dict[str, str | None] | None = None) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-m", *(a.format(port=self.port) for a in args)],
                                     cwd=ROOT, env=_environment(env), stdout=self.log,
                                     stderr=subprocess.STDOUT)

    @classmethod
    def uvicorn(cls, env: dict[str, str | None] | None = None) -> LiveServer:
        """The app as a user runs it under uvicorn (``service.app:create_app``), settings from ``env``."""
        return cls(["uvicorn", "--factory", "service.app:create_app", "--host", "127.0.0.1", "--port", "{port}",
                    "--log-level", "warning"], env)

    def wait_ready(self, timeout: float = 120.0) -> LiveServer:
        """Return once ``/readyz`` answers 200; a RuntimeError with the log if it exits or takes too long."""
        import httpx2

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.output()[-2000:]}")
            try:
                if httpx2.get(self.url + "/readyz", timeout=2).status_code == 200:
                    return self
            except httpx2.TransportError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"server did not become ready: {self.output()[-2000:]}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        self.log.close()

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read().decode(errors="replace")
