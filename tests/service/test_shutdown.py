"""Graceful shutdown of ``reglib serve``: SIGTERM with a request in flight.

The request in flight answers 200, a new request and ``/readyz`` get 503 while it runs, and the
process exits by itself with status 0.
"""
from __future__ import annotations

import signal
import time
from concurrent.futures import ThreadPoolExecutor

import httpx2
import pytest

from service import problems as P

pytestmark = pytest.mark.slow


def test_sigterm_drains_the_request_in_flight_then_exits_0(start_live_server, png_pair_of_size):
    server = start_live_server(workers=1, env={"REGLIB_SHUTDOWN_GRACE_S": "60", "REGLIB_MAX_PIXELS": "2000000"},
                               log_level="info")
    files = png_pair_of_size(700, 1000)   # 1 to 2 s of matching on one core
    with ThreadPoolExecutor(1) as threads:
        slow = threads.submit(httpx2.post, server.url + "/v1/match", timeout=120, data={"dense": "false"},
                              files={"image_a": ("a.png", files[0], "image/png"),
                                     "image_b": ("b.png", files[1], "image/png")})
        deadline = time.monotonic() + 30
        while httpx2.get(server.url + "/readyz", timeout=10).json().get("pending") != 1:
            assert time.monotonic() < deadline and not slow.done(), "the request never reached the worker"
            time.sleep(0.01)
        server.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 10
        while (ready := httpx2.get(server.url + "/readyz", timeout=10)).status_code == 200:
            assert time.monotonic() < deadline, "/readyz still 200 after SIGTERM"
            time.sleep(0.01)
        assert not slow.done(), "the slow request finished too soon to test the drain"
        assert ready.status_code == 503 and ready.json()["type"] == P.NOT_READY
        refused = httpx2.post(server.url + "/v1/filter", json={"src": [[0, 0]], "dst": [[0, 0]]}, timeout=10)
        assert refused.status_code == 503 and refused.json()["type"] == P.NOT_READY
        assert refused.headers["retry-after"] and refused.headers["x-request-id"]
        answer = slow.result(timeout=120)
    assert answer.status_code == 200, answer.text[:300]
    assert answer.json()["n_inliers"] > 0
    assert server.proc.wait(timeout=60) == 0, server.output()[-3000:]
    assert "drained" in server.output()
