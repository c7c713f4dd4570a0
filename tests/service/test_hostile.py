"""The service under hostile clients, over real HTTP (``reglib serve`` on 127.0.0.1): made-up methods in
/metrics, requests that stop arriving, huge JSON bodies, odd keys and uploads, slash redirects with a
forged Host, Cache-Control, cross-site posts without keys, and the cap on open connections.

Three servers: one with API keys and the default limits (the figures of the issue), one without keys and a
short body deadline, one with few connections allowed."""
from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import httpx2
import numpy as np
import pytest

from reglib.io import encode_image
from service.connections import HEALTH_RESERVE
from service.problems import CORS_REFUSED, NOT_READY, REQUEST_TIMEOUT, TOO_LARGE, UNAUTHORIZED

from .conftest import make_pair

pytestmark = pytest.mark.slow

KEY = "5e1f0c2a-reglib-hostile-test-key"
ALLOWED = "http://allowed.example"
EVIL = "http://evil.example"
CAP = 8
_RNG = np.random.default_rng(1)
SRC = _RNG.uniform(0, 300, (30, 2))
FILTER_BODY = {"src": SRC.tolist(), "dst": (SRC + [2.0, -3.0]).tolist()}


@pytest.fixture(scope="module")
def keyed(start_live_server, tmp_path_factory: pytest.TempPathFactory):
    keys = tmp_path_factory.mktemp("keys") / "keys.txt"
    keys.write_text(KEY + "\n")
    return start_live_server(workers=1, log_level="info", env={"REGLIB_API_KEYS_FILE": str(keys),
                                                               "REGLIB_MAX_PIXELS": "4000000"})


@pytest.fixture(scope="module")
def open_server(start_live_server):
    return start_live_server(workers=1, env={"REGLIB_CORS_ORIGINS": ALLOWED, "REGLIB_BODY_TIMEOUT_S": "2"})


@pytest.fixture(scope="module")
def capped(start_live_server):
    return start_live_server(workers=1, env={"REGLIB_MAX_CONNECTIONS": str(CAP), "REGLIB_HEADER_TIMEOUT_S": "60",
                                             "REGLIB_BODY_TIMEOUT_S": "60"})


def key_headers(**more: str) -> dict[str, str]:
    return {"X-API-Key": KEY, **more}


def timed_get(url: str) -> tuple[int, float]:
    start = time.monotonic()
    status = httpx2.get(url, timeout=10).status_code
    return status, time.monotonic() - start


def read_all(sock: socket.socket, limit_s: float) -> tuple[bytes, float]:
    """Everything the server sends until it closes (or ``limit_s`` passes), and when it closed."""
    start = time.monotonic()
    sock.settimeout(limit_s)
    data = b""
    try:
        while chunk := sock.recv(65536):
            data += chunk
    except (TimeoutError, ConnectionResetError):
        pass
    return data, time.monotonic() - start


@contextmanager
def held(port: int, payload: bytes, n: int) -> Iterator[list[socket.socket]]:
    """``n`` connections that each sent ``payload`` and then nothing."""
    socks = []
    try:
        for _ in range(n):
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(payload)
            socks.append(s)
        yield socks
    finally:
        for s in socks:
            s.close()


# -- with keys ------------------------------------------------------------------------------------------------

def test_made_up_methods_do_not_grow_the_metrics(keyed):
    before = len(httpx2.get(keyed.url + "/metrics", timeout=10).content)
    with httpx2.Client(timeout=10) as client:
        statuses = {client.request(f"M{i}", keyed.url + "/livez").status_code for i in range(300)}
    assert statuses == {405}
    text = httpx2.get(keyed.url + "/metrics", timeout=10).text
    assert len(text.encode()) - before < 20_000
    assert 'method="other",route="/livez",status="405"} 300.0' in text and 'method="M1"' not in text


def test_a_request_line_and_then_nothing_is_closed_with_a_408(keyed):
    with socket.create_connection(("127.0.0.1", keyed.port), timeout=10) as s:
        s.sendall(b"GET /livez HTTP/1.1\r\n")
        data, closed_after = read_all(s, 45)
    assert closed_after < 15, closed_after  # the default header deadline: 10 s
    assert data.startswith(b"HTTP/1.1 408 "), data[:200]
    assert json.loads(data.split(b"\r\n\r\n", 1)[1])["type"] == REQUEST_TIMEOUT


@pytest.mark.parametrize("chunked", [False, True])
def test_a_16_mb_json_body_is_a_quick_413_and_health_answers_meanwhile(keyed, chunked):
    points = "[" + ",".join(["[1.5,2.5]"] * 1_700_000) + "]"
    body = f'{{"src": {points}, "dst": {points}}}'.encode()
    assert len(body) > 16_000_000
    framing = "Transfer-Encoding: chunked" if chunked else f"Content-Length: {len(body)}"
    head = (f"POST /v1/filter HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nX-API-Key: {KEY}\r\n"
            f"{framing}\r\n\r\n").encode()
    health: list[tuple[int, float]] = []
    stop = threading.Event()

    def probe() -> None:
        while not stop.is_set():
            health.append(timed_get(keyed.url + "/livez"))
            time.sleep(0.05)

    def send(s: socket.socket) -> None:
        try:
            for i in range(0, len(body), 1 << 16):
                piece = body[i:i + (1 << 16)]
                s.sendall(b"%x\r\n%s\r\n" % (len(piece), piece) if chunked else piece)
            if chunked:
                s.sendall(b"0\r\n\r\n")
        except OSError:  # the server answered and closed before the whole body was sent: as wanted
            pass

    prober = threading.Thread(target=probe)
    prober.start()
    try:
        with socket.create_connection(("127.0.0.1", keyed.port), timeout=10) as s:
            start = time.monotonic()
            s.sendall(head)
            sender = threading.Thread(target=send, args=(s,))
            sender.start()
            s.settimeout(10)
            first = s.recv(65536)
            answered_after = time.monotonic() - start
            rest, _ = read_all(s, 10)
            sender.join(30)
        time.sleep(0.3)
    finally:
        stop.set()
        prober.join(20)
    answer = first + rest
    assert answer.startswith(b"HTTP/1.1 413 "), answer[:300]
    assert json.loads(answer.split(b"\r\n\r\n", 1)[1])["type"] == TOO_LARGE
    assert answered_after < 1.5, answered_after
    assert health and all(status == 200 for status, _ in health)
    assert max(seconds for _, seconds in health) < 0.5, health


def test_a_key_with_a_byte_beyond_ascii_is_a_401(keyed):
    for name, value in (("X-API-Key", b"caf\xe9-key"), ("Authorization", b"Bearer \xff\xfe"),
                        ("X-API-Key", KEY.encode() + b"\x80")):
        r = httpx2.post(keyed.url + "/v1/filter", json=FILTER_BODY, headers={name: value}, timeout=30)
        assert r.status_code == 401, (name, value, r.text)
        assert r.json()["type"] == UNAUTHORIZED and "ASCII" in r.json()["detail"]
    assert "Traceback" not in keyed.output()


@pytest.mark.parametrize("dtype", [np.float64, np.int32])
def test_an_rgb_tiff_of_floats_or_int32_is_never_a_5xx(keyed, dtype):
    a, b = make_pair(96, 128)
    scale = 1 / 255 if dtype == np.float64 else 1 << 20
    files = {name: (f"{name}.tif", encode_image((image.astype(np.float64) * scale).astype(dtype), ".tif"), "image/tiff")
             for name, image in (("image_a", a), ("image_b", b))}
    r = httpx2.post(keyed.url + "/v1/match", files=files, headers=key_headers(), timeout=120)
    assert r.status_code < 500, r.text


def test_a_filter_field_nested_20000_deep_is_a_4xx(keyed):
    pair = make_pair(64, 64)
    files = {name: (f"{name}.tif", encode_image(image, ".tif"), "image/tiff")
             for name, image in zip(("image_a", "image_b"), pair, strict=True)}
    r = httpx2.post(keyed.url + "/v1/match", files=files, data={"filter": "[" * 20_000 + "]" * 20_000},
                    headers=key_headers(), timeout=60)
    assert 400 <= r.status_code < 500, r.text
    assert "nested too deeply" in r.json()["detail"]
    deep = '{"src": [[0, 0]], "dst": [[0, 0]], "options": {"x": ' + "[" * 20_000 + "]" * 20_000 + "}}"
    r = httpx2.post(keyed.url + "/v1/filter", content=deep, timeout=60,
                    headers=key_headers(**{"Content-Type": "application/json"}))
    assert 400 <= r.status_code < 500, r.text


def test_api_answers_are_not_stored(keyed):
    answers = [httpx2.post(keyed.url + "/v1/filter", json=FILTER_BODY, headers=key_headers(), timeout=60),
               httpx2.post(keyed.url + "/v1/filter", json=FILTER_BODY, timeout=60),
               httpx2.post(keyed.url + "/v1/filter", json={"src": [[0, 0]]}, headers=key_headers(), timeout=60)]
    assert [r.status_code for r in answers] == [200, 401, 422]
    for r in answers:
        assert r.headers["cache-control"] == "no-store"


@pytest.mark.parametrize(("method", "path"), [("GET", "/docs/"), ("GET", "/redoc/"), ("POST", "/v1/filter/")])
def test_a_forged_host_never_gets_into_a_redirect(keyed, method, path):
    r = httpx2.request(method, keyed.url + path, headers=key_headers(Host="evil.example"), json=FILTER_BODY,
                       follow_redirects=False, timeout=30)
    assert r.status_code == 307, r.text
    assert r.headers["location"] == path.rstrip("/")  # relative: the way back to this server, whatever Host said


def test_a_decoding_over_the_memory_cap_is_a_413_and_the_worker_is_replaced(start_live_server):
    server = start_live_server(workers=1, env={"REGLIB_WORKER_MAX_MEMORY": str(100 << 20),
                                               "REGLIB_MAX_PIXELS": "25000000"})
    # 192 MB once decoded, a few hundred KB deflated
    ok, buf = cv2.imencode(".tif", np.zeros((4000, 4000, 3), np.float32), [cv2.IMWRITE_TIFF_COMPRESSION, 8])
    assert ok
    big = buf.tobytes()
    small = encode_image(make_pair(64, 64)[0], ".png")
    pid_before = server.worker_pids()
    r = httpx2.post(server.url + "/v1/match", files={"image_a": ("a.tif", big, "image/tiff"),
                                                     "image_b": ("b.png", small, "image/png")}, timeout=120)
    assert r.status_code == 413, r.text
    assert r.json()["type"] == TOO_LARGE and "memory" in r.json()["detail"]
    deadline = time.monotonic() + 60
    while server.worker_pids() in ([], pid_before) or httpx2.get(server.url + "/readyz", timeout=10).status_code != 200:
        assert time.monotonic() < deadline, server.output()[-2000:]
        time.sleep(0.2)
    assert 'reglib_worker_exits_total{reason="memory"} 1.0' in httpx2.get(server.url + "/metrics", timeout=10).text


# -- without keys ---------------------------------------------------------------------------------------------

def test_without_keys_a_cross_site_post_is_refused_before_its_body_is_read(open_server):
    url = open_server.url + "/v1/filter"
    refused = [{"Origin": EVIL, "Sec-Fetch-Site": "cross-site"}, {"Origin": EVIL},
               {"Origin": "null"}, {"Origin": "http://127.0.0.1:1", "Sec-Fetch-Site": "same-site"}]
    for headers in refused:
        r = httpx2.post(url, content=b'{"src": not json', timeout=30,
                        headers={"Content-Type": "application/json", **headers})
        assert r.status_code == 403, (headers, r.text)  # not 400: the body was never parsed
        assert r.headers["content-type"] == "application/problem+json" and r.json()["type"] == CORS_REFUSED
    pair = make_pair(64, 64)
    files = {name: (f"{name}.png", encode_image(image, ".png"), "image/png")
             for name, image in zip(("image_a", "image_b"), pair, strict=True)}
    r = httpx2.post(open_server.url + "/v1/match", files=files, timeout=60,
                    headers={"Origin": EVIL, "Sec-Fetch-Site": "cross-site"})
    assert r.status_code == 403 and r.json()["type"] == CORS_REFUSED
    allowed = [{}, {"Origin": open_server.url, "Sec-Fetch-Site": "same-origin"}, {"Origin": open_server.url},
               {"Origin": ALLOWED, "Sec-Fetch-Site": "cross-site"}, {"Sec-Fetch-Site": "none"}]
    for headers in allowed:
        r = httpx2.post(url, json=FILTER_BODY, headers=headers, timeout=60)
        assert r.status_code == 200, (headers, r.text)


def test_a_body_that_stops_arriving_is_closed_with_a_408(open_server):
    head = (b"POST /v1/filter HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: 1000\r\n\r\n")
    with socket.create_connection(("127.0.0.1", open_server.port), timeout=10) as s:
        s.sendall(head + b'{"src": [[1, 2],')
        time.sleep(1.0)
        s.sendall(b" [3, 4],")  # a piece in time: the deadline is the pause, not the whole body
        data, closed_after = read_all(s, 30)
    assert 1.5 < closed_after < 6, closed_after
    assert data.startswith(b"HTTP/1.1 408 "), data[:200]
    assert json.loads(data.split(b"\r\n\r\n", 1)[1])["type"] == REQUEST_TIMEOUT
    assert httpx2.get(open_server.url + "/livez", timeout=10).status_code == 200


# -- the cap on connections -----------------------------------------------------------------------------------

def test_slow_clients_past_the_cap_make_way_for_health_and_work(capped):
    with held(capped.port, b"GET /livez HTTP/1.1\r\nHost: x\r\n", 5 * CAP) as slow:
        for path in ("/livez", "/readyz"):
            status, seconds = timed_get(capped.url + path)
            assert status == 200 and seconds < 0.5, (path, seconds)
        r = httpx2.post(capped.url + "/v1/filter", json=FILTER_BODY, timeout=60)
        assert r.status_code == 200, r.text
        closed = 0
        for s in slow:  # the oldest ones were closed to make way
            s.settimeout(0.5)
            try:
                closed += s.recv(1) == b""
            except ConnectionResetError:
                closed += 1
            except TimeoutError:
                pass
        assert closed >= 4 * CAP, closed


def test_with_every_connection_mid_request_health_still_answers(capped):
    payload = (b"POST /v1/filter HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
               b"Content-Length: 1000\r\n\r\n{")
    with held(capped.port, payload, CAP):
        time.sleep(0.3)
        for _ in range(2 * HEALTH_RESERVE):
            for path in ("/livez", "/readyz"):
                status, seconds = timed_get(capped.url + path)
                assert status == 200 and seconds < 0.5, (path, seconds)
        r = httpx2.post(capped.url + "/v1/filter", json=FILTER_BODY, timeout=60)
        assert r.status_code == 503 and r.json()["type"] == NOT_READY, r.text
    deadline = time.monotonic() + 10
    while httpx2.post(capped.url + "/v1/filter", json=FILTER_BODY, timeout=60).status_code != 200:
        assert time.monotonic() < deadline
        time.sleep(0.1)


def test_settings_name_the_defaults_the_readme_gives():
    from service.config import Settings

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    settings = Settings()
    assert settings.header_timeout_s <= 40
    for name in ("REGLIB_HEADER_TIMEOUT_S", "REGLIB_BODY_TIMEOUT_S", "REGLIB_MAX_CONNECTIONS",
                 "REGLIB_MAX_JSON_BYTES"):
        assert name in text, name
