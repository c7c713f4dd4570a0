"""A service fit to leave localhost, over real HTTP (``reglib serve`` on 127.0.0.1): API keys by either header,
the open endpoints, the per-key limit in flight, CORS preflights, the security headers, keys kept out of the
logs, SIGHUP re-reading the keys file, and the warning of a bind beyond loopback with no keys."""
from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx2
import numpy as np
import pytest

from service.auth import key_id
from service.problems import KEY_BUSY, UNAUTHORIZED

from .conftest import free_port

pytestmark = pytest.mark.slow

KEY_A = "a7f3c9e1-reglib-test-key-one"
KEY_B = "0b5d2e8f-reglib-test-key-two"
KEY_NEW = "c4e6a8b0-reglib-test-key-three"
ALLOWED = "http://allowed.example"
EVIL = "http://evil.example"

_RNG = np.random.default_rng(0)
SRC = _RNG.uniform(0, 300, (40, 2))
FILTER_BODY = {"src": SRC.tolist(), "dst": (SRC + [3.0, 4.0]).tolist()}


@pytest.fixture(scope="module")
def keys_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("keys") / "keys.txt"
    path.write_text(f"# the test's callers\n{KEY_A}\n\n   {KEY_B}   \n# {KEY_NEW} is not a key: a comment\n")
    return path


@pytest.fixture(scope="module")
def server(start_live_server, keys_file):
    return start_live_server(workers=1, log_level="info", env={
        "REGLIB_API_KEYS_FILE": str(keys_file), "REGLIB_CORS_ORIGINS": f"{ALLOWED}, https://other.example:8443",
        "REGLIB_MAX_IN_FLIGHT_PER_KEY": "1", "REGLIB_QUEUE_SIZE": "4"})


def post_filter(server, **headers: str) -> httpx2.Response:
    return httpx2.post(server.url + "/v1/filter", json=FILTER_BODY, headers=headers, timeout=60)


def policy(response: httpx2.Response) -> dict[str, list[str]]:
    """The Content-Security-Policy as {directive: [sources]}."""
    parts = [p.split() for p in response.headers["content-security-policy"].split(";") if p.strip()]
    return {p[0]: p[1:] for p in parts}


def assert_security_headers(response: httpx2.Response) -> None:
    csp = policy(response)
    scripts = csp.get("script-src", csp.get("default-src"))
    assert scripts is not None and "'unsafe-inline'" not in scripts, csp
    assert csp["frame-ancestors"] == ["'none'"]
    assert response.headers["x-frame-options"] == "DENY"
    assert response.headers["x-content-type-options"] == "nosniff"
    assert response.headers["referrer-policy"] == "no-referrer"


def test_no_key_or_a_wrong_one_is_a_401_problem(server):
    cases = [({}, 'Bearer realm="reglib"', "needs an API key"),
             ({"Authorization": "Bearer not-a-key"}, 'Bearer realm="reglib", error="invalid_token"', "not one of"),
             ({"X-API-Key": KEY_A + "x"}, 'Bearer realm="reglib", error="invalid_token"', "not one of"),
             ({"X-API-Key": KEY_NEW}, 'Bearer realm="reglib", error="invalid_token"', "not one of"),  # a comment
             ({"Authorization": f"Basic {KEY_A}"}, 'Bearer realm="reglib", error="invalid_token"', "Bearer <key>"),
             ({"Authorization": f"Bearer {KEY_A}", "X-API-Key": KEY_B}, 'Bearer realm="reglib", error="invalid_token"',
              "two different keys")]
    for headers, challenge, said in cases:
        r = post_filter(server, **headers)
        assert r.status_code == 401, headers
        assert r.headers["content-type"] == "application/problem+json"
        assert r.headers["www-authenticate"] == challenge
        body = r.json()
        assert body["type"] == UNAUTHORIZED and body["status"] == 401 and said in body["detail"], body
        assert KEY_A not in r.text and KEY_B not in r.text
    # the image endpoints too, before their bodies are read
    r = httpx2.post(server.url + "/v1/match", files={"image_a": ("a.png", b"x" * 10)}, timeout=30)
    assert r.status_code == 401 and r.json()["type"] == UNAUTHORIZED


def test_the_right_key_by_either_header_is_let_in(server):
    for headers in ({"Authorization": f"Bearer {KEY_A}"}, {"authorization": f"bearer {KEY_B}"},
                    {"X-API-Key": KEY_A}, {"X-API-Key": KEY_B},
                    {"Authorization": f"Bearer {KEY_A}", "X-API-Key": KEY_A}):
        r = post_filter(server, **headers)
        assert r.status_code == 200, (headers, r.text)
        result = r.json()
        assert result["n_inliers"] == 40 and result["converged"] is True


def test_the_health_probes_the_page_and_the_docs_stay_open(server):
    for path in ("/livez", "/readyz", "/", "/docs", "/redoc", "/openapi.json", "/static/app.js", "/examples",
                 "/metrics"):  # /metrics: open to a request on a loopback address (REGLIB_METRICS_ACCESS=auto)
        assert httpx2.get(server.url + path, timeout=30).status_code == 200, path
    doc = httpx2.get(server.url + "/openapi.json", timeout=30).json()
    assert set(doc["components"]["securitySchemes"]) == {"bearer", "apiKey"}
    assert doc["paths"]["/v1/filter"]["post"]["security"] == [{"bearer": []}, {"apiKey": []}]
    assert "401" in doc["paths"]["/v1/filter"]["post"]["responses"]


def _metric(server, name: str, key: str) -> float:
    text = httpx2.get(server.url + "/metrics", timeout=30).text
    m = re.search(rf'^{name}\{{key="{key}"\}} (\S+)$', text, re.M)
    return float(m.group(1)) if m else 0.0


def test_one_key_beyond_its_limit_in_flight_gets_429_and_the_others_go_on(server):
    body = json.dumps(FILTER_BODY).encode()
    head = (f"POST /v1/filter HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\nX-API-Key: {KEY_A}\r\nConnection: close\r\n\r\n").encode()
    rejected = _metric(server, "reglib_key_rejections_total", key_id(KEY_A))
    with socket.create_connection(("127.0.0.1", server.port), timeout=60) as held:
        held.sendall(head + body[:20])  # in flight: its body is still on its way
        deadline = time.monotonic() + 30
        while _metric(server, "reglib_key_in_flight", key_id(KEY_A)) < 1:
            assert time.monotonic() < deadline, "the held request was never counted in flight"
            time.sleep(0.05)
        busy = post_filter(server, **{"X-API-Key": KEY_A})
        assert busy.status_code == 429 and busy.headers["retry-after"] == "1"
        assert busy.headers["content-type"] == "application/problem+json" and busy.json()["type"] == KEY_BUSY
        assert post_filter(server, **{"X-API-Key": KEY_B}).status_code == 200  # another caller is not held up
        held.sendall(body[20:])
        answer = b""
        while chunk := held.recv(65536):
            answer += chunk
    assert answer.startswith(b"HTTP/1.1 200 "), answer[:200]
    assert post_filter(server, **{"X-API-Key": KEY_A}).status_code == 200  # its slot is free again
    assert _metric(server, "reglib_key_rejections_total", key_id(KEY_A)) == rejected + 1
    assert _metric(server, "reglib_key_in_flight", key_id(KEY_A)) == 0
    assert _metric(server, "reglib_key_requests_total", key_id(KEY_B)) >= 1


def test_cors_preflights_allow_the_named_origins_only(server):
    ask = {"Access-Control-Request-Method": "POST", "Access-Control-Request-Headers": "authorization, content-type"}
    evil = httpx2.options(server.url + "/v1/filter", headers={"Origin": EVIL, **ask}, timeout=30)
    assert evil.status_code == 403 and evil.headers["content-type"] == "application/problem+json"
    assert not [h for h in evil.headers if h.lower().startswith("access-control-allow")]
    for origin in (ALLOWED, "https://other.example:8443"):
        for headers in ("authorization, content-type", "x-api-key, content-type"):
            ok = httpx2.options(server.url + "/v1/filter", timeout=30, headers={
                "Origin": origin, "Access-Control-Request-Method": "POST", "Access-Control-Request-Headers": headers})
            assert ok.status_code == 204, ok.text
            assert ok.headers["access-control-allow-origin"] == origin
            allowed = {h.strip() for h in ok.headers["access-control-allow-headers"].split(",")}
            assert {"authorization", "x-api-key", "content-type"} <= allowed
            assert "POST" in ok.headers["access-control-allow-methods"]
    odd = httpx2.options(server.url + "/v1/filter", timeout=30, headers={
        "Origin": ALLOWED, "Access-Control-Request-Method": "DELETE"})
    assert odd.status_code == 403 and "access-control-allow-origin" not in odd.headers
    # the answers themselves: readable by an allowed origin's page (a 401 too, so the page can ask for a key)
    answer = post_filter(server, Origin=ALLOWED, **{"X-API-Key": KEY_A})
    assert answer.status_code == 200 and answer.headers["access-control-allow-origin"] == ALLOWED
    assert "X-Request-ID" in answer.headers["access-control-expose-headers"]
    refused = post_filter(server, Origin=ALLOWED)
    assert refused.status_code == 401 and refused.headers["access-control-allow-origin"] == ALLOWED
    assert "access-control-allow-origin" not in post_filter(server, Origin=EVIL, **{"X-API-Key": KEY_A}).headers


def test_every_answer_carries_the_security_headers(server):
    page = httpx2.get(server.url + "/", timeout=30)
    assert page.status_code == 200
    assert_security_headers(page)
    assert policy(page)["script-src"] == ["'self'"] and policy(page)["style-src"] == ["'self'"]
    ok = post_filter(server, **{"X-API-Key": KEY_A})
    assert ok.status_code == 200
    answers = [ok, post_filter(server), post_filter(server, Origin=ALLOWED, **{"X-API-Key": KEY_B}),
               httpx2.post(server.url + "/v1/filter", json={"src": [[0, 0]]}, headers={"X-API-Key": KEY_A},
                           timeout=30),
               httpx2.get(server.url + "/no-such-page", timeout=30), httpx2.get(server.url + "/docs", timeout=30),
               httpx2.get(server.url + "/redoc", timeout=30), httpx2.get(server.url + "/static/app.js", timeout=30)]
    assert [r.status_code for r in answers] == [200, 401, 200, 422, 404, 200, 200, 200]
    for r in answers:
        assert_security_headers(r)
    assert policy(answers[0])["default-src"] == ["'none'"]  # the API's answers load nothing
    docs = policy(answers[5])["script-src"]
    assert docs[0] == "'self'" and len(docs) == 2 and docs[1].startswith("'sha256-")  # the start-up script's hash


def test_keys_never_reach_the_log_and_callers_are_named_by_id(server):
    post_filter(server, **{"Authorization": f"Bearer {KEY_B}"})
    post_filter(server, **{"X-API-Key": KEY_A + "x"})
    deadline = time.monotonic() + 10
    while f"key {key_id(KEY_B)}" not in server.output():
        assert time.monotonic() < deadline, server.output()[-3000:]
        time.sleep(0.1)
    log = server.output()
    for secret in (KEY_A, KEY_B, KEY_NEW, KEY_A + "x"):
        assert secret not in log
    assert re.search(rf"POST /v1/filter 200 [0-9.]+ ms key {key_id(KEY_B)}", log), log[-3000:]
    assert re.search(r"POST /v1/filter 401 [0-9.]+ ms\s", log)


def test_sighup_rereads_the_keys_file(server, keys_file):
    keys_file.write_text(f"{KEY_NEW}\n{KEY_B}\n")
    server.proc.send_signal(signal.SIGHUP)
    deadline = time.monotonic() + 20
    while post_filter(server, **{"X-API-Key": KEY_NEW}).status_code != 200:
        assert time.monotonic() < deadline and server.proc.poll() is None, server.output()[-3000:]
        time.sleep(0.1)
    assert post_filter(server, **{"X-API-Key": KEY_A}).status_code == 401
    assert post_filter(server, **{"X-API-Key": KEY_B}).status_code == 200
    # a file that cannot be used keeps the keys read before, and says why
    keys_file.write_text("# nothing but a comment\n")
    server.proc.send_signal(signal.SIGHUP)
    deadline = time.monotonic() + 20
    while "API keys not reloaded" not in server.output():
        assert time.monotonic() < deadline, server.output()[-3000:]
        time.sleep(0.1)
    assert "holds no key" in server.output()
    assert post_filter(server, **{"X-API-Key": KEY_NEW}).status_code == 200
    assert server.proc.poll() is None


def _serve_on(host: str, env: dict[str, str]) -> tuple[str, str]:
    """Run uvicorn on ``host`` until it is ready and a moment more; its log, and the reason it stopped."""
    port = free_port()
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen([sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--host",
                                 host, "--port", str(port), "--log-level", "info"],
                                env={**os.environ, "REGLIB_WORKERS": "1", **env}, stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 60
            while True:
                assert proc.poll() is None and time.monotonic() < deadline
                try:
                    if httpx2.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200:
                        break
                except httpx2.TransportError:
                    pass
                time.sleep(0.2)
            time.sleep(1.5)  # the check runs once the server listens: give it time to speak
        finally:
            proc.terminate()
            proc.wait(timeout=30)
        log.seek(0)
        return log.read().decode(errors="replace"), str(proc.returncode)


@pytest.mark.parametrize(("host", "keys", "warned"), [("0.0.0.0", False, True), ("127.0.0.1", False, False),
                                                       ("0.0.0.0", True, False)])
def test_a_bind_beyond_loopback_without_keys_warns_once(host, keys, warned, keys_file, tmp_path):
    env = {}
    if keys:
        path = tmp_path / "keys.txt"
        path.write_text(KEY_A + "\n")
        env["REGLIB_API_KEYS_FILE"] = str(path)
    log, _ = _serve_on(host, env)
    lines = [line for line in log.splitlines() if "has no API keys" in line]
    assert len(lines) == (1 if warned else 0), log[-3000:]
    if warned:
        assert "listens on 0.0.0.0" in lines[0] and "REGLIB_API_KEYS_FILE" in lines[0]
