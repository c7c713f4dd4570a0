"""Fixtures of the service tests: one in-process app per session, test images, a real uvicorn."""
from __future__ import annotations

import os
from collections.abc import Callable, Iterator

import cv2
import numpy as np
import pytest
import skimage.data
from fastapi.testclient import TestClient

from service.app import create_app
from service.config import Settings

from ..conftest import LiveServer as BaseServer
from ..conftest import free_port

__all__ = ["LiveServer", "free_port"]


def make_pair(height: int = 256, width: int = 320) -> tuple[np.ndarray, np.ndarray]:
    """Image a (a crop of scikit-image's bundled astronaut) and b = a under a known smooth warp (RGB uint8)."""
    base = skimage.data.astronaut()
    a = np.ascontiguousarray(cv2.resize(base, (width, height), interpolation=cv2.INTER_AREA))
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    # b(p) = a(p - d(p)): b shows a shifted by about (6, -4) px plus a gentle bend.
    map_x = cols - 6.0 - 3.0 * np.sin(rows / 60.0)
    map_y = rows + 4.0 - 2.0 * np.cos(cols / 70.0)
    b = cv2.remap(a, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return a, b


def encode(image: np.ndarray, ext: str = ".png") -> bytes:
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(ext, bgr)
    assert ok
    return buf.tobytes()


@pytest.fixture(scope="session")
def settings() -> Settings:
    return Settings(workers=2, queue_size=8, compute_timeout_s=120, max_upload_bytes=4 * 1024 * 1024,
                    max_json_bytes=2 * 1024 * 1024, max_pixels=2_000_000, max_points=5_000)


@pytest.fixture(scope="session")
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


@pytest.fixture(scope="session")
def image_pair() -> tuple[np.ndarray, np.ndarray]:
    return make_pair()


@pytest.fixture(scope="session")
def png_pair(image_pair: tuple[np.ndarray, np.ndarray]) -> tuple[bytes, bytes]:
    return encode(image_pair[0]), encode(image_pair[1])


class LiveServer(BaseServer):
    """``reglib serve`` in a subprocess on 127.0.0.1; stopped (SIGTERM, then SIGKILL) at teardown."""

    def __init__(self, workers: int, env: dict[str, str | None], log_level: str = "warning") -> None:
        super().__init__(["reglib.cli", "serve", "--host", "127.0.0.1", "--port", "{port}", "--workers",
                          str(workers), "--log-level", log_level], env)

    def wait_ready(self, timeout: float = 60.0) -> LiveServer:
        super().wait_ready(timeout)
        return self

    def worker_pids(self) -> list[int]:
        """The pids of the server's compute workers (its spawned children other than the resource tracker)."""
        children: list[int] = []
        try:
            for task in os.listdir(f"/proc/{self.proc.pid}/task"):
                with open(f"/proc/{self.proc.pid}/task/{task}/children", encoding="ascii") as f:
                    children += [int(pid) for pid in f.read().split()]
        except OSError:
            return []
        pids = []
        for pid in children:
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    cmdline = f.read()
            except OSError:
                continue
            if b"spawn_main" in cmdline and b"resource_tracker" not in cmdline:
                pids.append(pid)
        return sorted(set(pids))


@pytest.fixture(scope="session")
def live_server() -> Iterator[LiveServer]:
    server = LiveServer(workers=2, env={"REGLIB_QUEUE_SIZE": "2", "REGLIB_MAX_PIXELS": "2000000"})
    try:
        server.wait_ready()
        yield server
    finally:
        server.stop()


@pytest.fixture(scope="module")
def start_live_server() -> Iterator[Callable[..., LiveServer]]:
    """``start(workers=2, env={...}, log_level="warning")`` -> a ready LiveServer; all stopped at module end."""
    servers: list[LiveServer] = []

    def start(workers: int = 2, env: dict[str, str] | None = None, log_level: str = "warning") -> LiveServer:
        server = LiveServer(workers=workers, env=env or {}, log_level=log_level)
        servers.append(server)
        server.wait_ready()
        return server

    try:
        yield start
    finally:
        for server in servers:
            server.stop()


@pytest.fixture(scope="session")
def png_pair_of_size() -> Callable[[int, int], tuple[bytes, bytes]]:
    """``(height, width) -> (png a, png b)``: :func:`make_pair` at that size, PNG-encoded."""
    def pair(height: int, width: int) -> tuple[bytes, bytes]:
        a, b = make_pair(height, width)
        return encode(a), encode(b)

    return pair
