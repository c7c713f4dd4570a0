"""Faults against a real uvicorn on 127.0.0.1: killed workers, a request that crashes its worker, a job
over the worker memory cap, readiness while a worker is replaced, request ids and JSON log lines.

One server for the module: 2 workers, JSON logs at info, a 300 MiB worker memory cap (a 1000 x 700
match fits in it, a 1400 x 1400 one does not), and the fault-injection hook on (``X-Reglib-Fault:
crash`` makes a job kill its worker; off by default, see service/config.py).
"""
from __future__ import annotations

import json
import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor

import httpx2
import pytest

from service import problems as P

pytestmark = pytest.mark.slow

CAP = 300 << 20
POINTS = {"src": [[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]],
          "dst": [[1.0, 1.0], [11.0, 1.0], [1.0, 11.0], [11.0, 11.0]]}


@pytest.fixture(scope="module")
def server(start_live_server):
    return start_live_server(workers=2, log_level="info", env={
        "REGLIB_FAULT_INJECTION": "true", "REGLIB_LOG_FORMAT": "json", "REGLIB_WORKER_MAX_MEMORY": str(CAP),
        "REGLIB_MAX_PIXELS": "2000000", "REGLIB_QUEUE_SIZE": "4", "REGLIB_COMPUTE_TIMEOUT_S": "120"})


def files_of(pair):
    return {"image_a": ("a.png", pair[0], "image/png"), "image_b": ("b.png", pair[1], "image/png")}


def readyz(server):
    return httpx2.get(server.url + "/readyz", timeout=10)


def wait_until(predicate, timeout: float, step: float = 0.02):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    return None


def wait_whole(server, timeout: float = 60.0) -> list[int]:
    """Wait until /readyz is 200 with both workers up; returns their pids."""
    assert wait_until(lambda: readyz(server).status_code == 200 and len(server.worker_pids()) == 2, timeout), \
        server.output()[-3000:]
    return server.worker_pids()


def log_lines(server) -> list[dict]:
    """The server's log lines so far, parsed (a last line still being written is left for the next read)."""
    text = server.output()
    complete = text[:text.rfind("\n") + 1]
    return [json.loads(line) for line in complete.splitlines() if line.strip()]


def access_logged(server, request_id: str, timeout: float = 10.0) -> list[dict]:
    """The lines of ``request_id`` once its access line is there: the server writes that line after the
    response has been sent, so a client can read the log before it."""
    def lines() -> list[dict] | None:
        got = [line for line in log_lines(server) if line.get("request_id") == request_id]
        return got if any(line["logger"] == "service.access" for line in got) else None

    return wait_until(lines, timeout) or [line for line in log_lines(server) if line.get("request_id") == request_id]


def test_a_killed_worker_fails_no_other_request(server, png_pair_of_size):
    pids = wait_whole(server)
    files = files_of(png_pair_of_size(700, 1000))
    with ThreadPoolExecutor(2) as threads:
        posts = [threads.submit(httpx2.post, server.url + "/v1/match", files=files, data={"dense": "false"},
                                headers={"X-Request-ID": f"two-in-flight-{k}"}, timeout=120) for k in range(2)]
        assert wait_until(lambda: readyz(server).json().get("pending") == 2, 30), "both requests never ran"
        os.kill(pids[0], signal.SIGKILL)
        answers = [post.result(timeout=120) for post in posts]
    # The request on the healthy worker finishes; the one on the killed worker is retried on a fresh one.
    assert [a.status_code for a in answers] == [200, 200], [a.text[:300] for a in answers]
    assert answers[0].json()["inliers"] == answers[1].json()["inliers"]
    retried = [line for line in log_lines(server) if "retrying it once" in line["message"]]
    assert [line.get("request_id") for line in retried if line.get("request_id", "").startswith("two-in-flight")]
    new_pids = wait_whole(server)
    assert pids[0] not in new_pids and pids[1] in new_pids


def test_readyz_is_503_while_a_worker_is_replaced(server):
    pids = wait_whole(server)
    os.kill(pids[1], signal.SIGKILL)  # an idle worker: no request is needed to notice it
    down = wait_until(lambda: (r := readyz(server)).status_code == 503 and r, 10, step=0.005)
    assert down, "readyz never said 503 after a worker died"
    assert down.json()["type"] == P.NOT_READY and down.json()["alive"] == 1 and down.headers["retry-after"]
    new_pids = wait_whole(server)
    assert pids[1] not in new_pids and pids[0] in new_pids
    metrics = httpx2.get(server.url + "/metrics", timeout=10).text
    assert 'reglib_worker_exits_total{reason="crashed"}' in metrics and "reglib_workers_alive 2.0" in metrics


def test_a_request_that_crashes_its_worker_twice_gets_500(server):
    wait_whole(server)
    r = httpx2.post(server.url + "/v1/filter", json=POINTS, timeout=120,
                    headers={"X-Reglib-Fault": "crash", "X-Request-ID": "crash-twice-1"})
    assert r.status_code == 500, r.text
    assert r.headers["content-type"].startswith(P.MEDIA_TYPE) and r.json()["type"] == P.WORKER_CRASHED
    assert r.headers["x-request-id"] == "crash-twice-1"
    logged = access_logged(server, "crash-twice-1")
    assert any(line["level"] == "error" and "crashed a worker twice" in line["message"] for line in logged), logged
    assert any(line["logger"] == "service.access" and line["status"] == 500 for line in logged), logged
    wait_whole(server)
    assert httpx2.post(server.url + "/v1/filter", json=POINTS, timeout=60).status_code == 200


def test_a_job_over_the_memory_cap_is_413_and_the_service_still_serves(server, png_pair_of_size, png_pair):
    wait_whole(server)
    r = httpx2.post(server.url + "/v1/match", files=files_of(png_pair_of_size(1400, 1400)), timeout=120)
    assert r.status_code == 413, r.text[:300]
    assert r.json()["type"] == P.TOO_LARGE and "memory" in r.json()["detail"]
    wait_whole(server)
    r = httpx2.post(server.url + "/v1/match", files=files_of(png_pair), data={"dense": "false"}, timeout=120)
    assert r.status_code == 200, r.text[:300]
    assert 'reglib_worker_exits_total{reason="memory"}' in httpx2.get(server.url + "/metrics", timeout=10).text


@pytest.mark.parametrize("given", [None, b"", b"has spaces", b"x" * 129, b"caf\xe9", b"a\\b"])
def test_a_request_id_is_generated_when_none_or_not_sane(server, given):
    headers = {} if given is None else {"X-Request-ID": given}
    r = httpx2.get(server.url + "/livez", headers=headers, timeout=10)
    rid = r.headers["x-request-id"]
    assert rid.encode() != given and len(rid) == 32 and int(rid, 16) >= 0


def test_a_sane_request_id_is_echoed_on_every_answer(server):
    rid = "Client-42.a:b/c+d=e~f_g"
    assert httpx2.get(server.url + "/readyz", headers={"X-Request-ID": rid}, timeout=10).headers["x-request-id"] == rid
    r = httpx2.post(server.url + "/v1/filter", content=b"{}", headers={"X-Request-ID": rid,
                                                                       "Content-Type": "text/plain"}, timeout=10)
    assert r.status_code == 415 and r.headers["x-request-id"] == rid   # refused by the request guard
    r = httpx2.get(server.url + "/no/such/page", headers={"X-Request-ID": rid}, timeout=10)
    assert r.status_code == 404 and r.headers["x-request-id"] == rid
    r = httpx2.post(server.url + "/v1/filter", json=POINTS, headers={"X-Request-ID": rid}, timeout=60)
    assert r.status_code == 200 and r.headers["x-request-id"] == rid


def test_every_log_line_is_one_json_object(server):
    httpx2.post(server.url + "/v1/filter", json=POINTS, headers={"X-Request-ID": "json-log-1"}, timeout=60)
    access_logged(server, "json-log-1")
    lines = log_lines(server)   # raises if any complete line is not JSON
    assert all({"time", "level", "logger", "message"} <= set(line) for line in lines)
    access = [line for line in lines if line.get("request_id") == "json-log-1" and line["logger"] == "service.access"]
    assert len(access) == 1
    assert access[0]["method"] == "POST" and access[0]["path"] == "/v1/filter" and access[0]["status"] == 200
    assert access[0]["duration_ms"] > 0
    assert any(line["logger"].startswith("uvicorn") for line in lines)   # uvicorn's own lines too
