"""Overload (429), not ready (503), timeout (504), health and metrics, on a small pool; crashes and the
memory cap on the pool itself."""
from __future__ import annotations

import asyncio
import os
import signal
import time

import cv2
import pytest
from fastapi.testclient import TestClient

from service import problems as P
from service.app import create_app
from service.config import Settings
from service.pool import ComputeTimeout, NotReady, WorkerOutOfMemory, WorkPool

POINTS = {"src": [[0.0, 0.0], [1.0, 1.0]], "dst": [[0.0, 0.0], [1.0, 1.0]]}


@pytest.fixture
def anyio_backend():
    return "asyncio"


@pytest.fixture(scope="module")
def one_worker():
    settings = Settings(workers=1, queue_size=1, compute_timeout_s=1.0, retry_after_s=3)
    app = create_app(settings)
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c, app


def occupy(client, app, seconds: float):
    """Keep the one worker busy with a plain time.sleep submitted through the app's own pool."""
    return client.portal.start_task_soon(app.state.pool.run, time.sleep, seconds)


def test_queue_full_is_429_with_retry_after(one_worker):
    client, app = one_worker
    busy = occupy(client, app, 0.8)            # the worker
    queued = client.portal.start_task_soon(app.state.pool.run, time.sleep, 0.0)  # the one queue place
    deadline = time.monotonic() + 5
    while app.state.pool.pending < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    r = client.post("/v1/filter", json=POINTS)
    assert r.status_code == 429
    assert r.headers["retry-after"] == "3"
    assert r.json()["type"] == P.OVERLOADED
    busy.result(timeout=10)
    queued.result(timeout=10)
    r = client.post("/v1/filter", json=POINTS)   # and then it serves again
    assert r.status_code == 200
    assert 'reglib_rejections_total{reason="overloaded"}' in client.get("/metrics").text


def test_wait_past_the_limit_is_504(one_worker):
    client, app = one_worker
    busy = occupy(client, app, 2.0)
    r = client.post("/v1/filter", json=POINTS)   # queued behind the sleep, past the 1 s limit
    assert r.status_code == 504 and r.json()["type"] == P.TIMEOUT
    with pytest.raises(ComputeTimeout):
        busy.result(timeout=10)
    deadline = time.monotonic() + 60
    while (app.state.pool.pending or not app.state.pool.ready) and time.monotonic() < deadline:
        time.sleep(0.05)   # the worker that ran past the limit is killed and replaced
    assert client.post("/v1/filter", json=POINTS).status_code == 200


def test_not_ready_before_the_pool_starts():
    client = TestClient(create_app(Settings(workers=1)), raise_server_exceptions=False)  # no lifespan: no pool
    r = client.get("/readyz")
    assert r.status_code == 503 and r.json()["type"] == P.NOT_READY and r.headers["retry-after"]
    r = client.post("/v1/filter", json=POINTS)
    assert r.status_code == 503 and r.json()["type"] == P.NOT_READY
    assert client.get("/livez").status_code == 200


def test_health_and_metrics(client):
    assert client.get("/livez").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["status"] == "ready"
    client.post("/v1/filter", json=POINTS)
    text = client.get("/metrics").text
    for name in ("reglib_http_requests_total", "reglib_http_request_duration_seconds_bucket",
                 "reglib_http_in_flight", "reglib_work_running", "reglib_work_queued", "reglib_rejections"):
        assert name in text, name
    assert 'route="/v1/filter"' in text


@pytest.mark.anyio
async def test_pool_refuses_before_start_and_after_stop():
    pool = WorkPool(workers=1, queue_size=0, timeout=5, retry_after=1, opencv_max_pixels=10**6)
    with pytest.raises(NotReady):
        await pool.run(time.sleep, 0)
    await pool.start()
    try:
        assert pool.ready
        assert await pool.run(divmod, 7, 2) == (3, 1)
        assert await pool.run(os.getenv, "OPENCV_IO_MAX_IMAGE_PIXELS") == str(10**6)  # OpenCV's own guard
        assert await pool.run(cv2.getNumThreads) == 1
    finally:
        await pool.stop()
    with pytest.raises(NotReady):
        await pool.run(time.sleep, 0)



async def wait_ready(pool: WorkPool, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not pool.ready:
        assert time.monotonic() < deadline, "the pool did not come back"
        await asyncio.sleep(0.02)


@pytest.mark.slow
@pytest.mark.anyio
async def test_a_crash_is_retried_once_on_a_fresh_worker_and_the_memory_cap_holds():
    exits: list[str] = []
    pool = WorkPool(workers=1, queue_size=2, timeout=120, retry_after=1, opencv_max_pixels=10**6,
                    max_memory=256 << 20, on_exit=exits.append)
    await pool.start()
    try:
        first = pool.pids[0]
        # os.kill(first, SIGKILL) kills the worker that runs it; its retry, on a fresh worker, finds no
        # such process: the error proves the job ran twice, the second time elsewhere. (A job that kills
        # every worker it runs on is a WorkerCrashed: tests/service/test_faults.py.)
        with pytest.raises(ProcessLookupError):
            await pool.run(os.kill, first, signal.SIGKILL)
        await wait_ready(pool)
        assert pool.pids != [first] and exits == ["crashed"]
        with pytest.raises(WorkerOutOfMemory):
            await pool.run(bytearray, 512 << 20)   # over the 256 MiB a job may add
        await wait_ready(pool)
        assert exits == ["crashed", "memory"]
        assert await pool.run(divmod, 7, 2) == (3, 1)   # and it serves again
        assert pool.pending == 0
    finally:
        await pool.stop()
    assert not pool.ready and pool.alive == 0
