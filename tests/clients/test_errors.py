"""Retries and error parsing, against a mock transport that answers what each test scripts."""
from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime

import httpx2
import numpy as np
import pytest

from reglib import KernelWarp
from reglib_client import (
    ApiError,
    AsyncClient,
    Client,
    InvalidInput,
    MalformedResponse,
    Overloaded,
    RetryPolicy,
    Timeout,
    TooLarge,
    Unreachable,
    _client,
)

PROBLEM = "application/problem+json"
BASE = "https://reglib.dev/problems/"
SRC = [[0.0, 0.0], [1.0, 2.0], [3.0, 1.0]]


def filter_body() -> dict:
    return {"n_matches": 3, "n_inliers": 2, "inliers": [0, 2], "scores": [0.9, 0.1, 0.8],
            "transform": KernelWarp.identity(2).to_dict(), "converged": True, "reason": None, "sigma": 0.5,
            "n_iter": 4, "seed": 0, "timings_ms": {"filter": 1.5}}


def problem(status: int, kind: str, detail: str = "went wrong", headers: dict | None = None) -> httpx2.Response:
    return httpx2.Response(status, headers={"content-type": PROBLEM, **(headers or {})},
                           content=json.dumps({"type": BASE + kind, "title": kind.title(), "status": status,
                                               "detail": detail}).encode())


class Script:
    """A mock transport handler that answers the scripted responses in order and records requests."""

    def __init__(self, *answers: httpx2.Response | Exception | Callable[[httpx2.Request], httpx2.Response]) -> None:
        self.answers = list(answers)
        self.requests: list[httpx2.Request] = []

    def __call__(self, request: httpx2.Request) -> httpx2.Response:
        self.requests.append(request)
        answer = self.answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        if callable(answer):
            return answer(request)
        return answer


@pytest.fixture()
def sleeps(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """Record the client's waits instead of sleeping."""
    waited: list[float] = []
    monkeypatch.setattr(_client, "_sleep", waited.append)

    async def fake_async_sleep(seconds: float) -> None:
        waited.append(seconds)
    monkeypatch.setattr(_client, "_async_sleep", fake_async_sleep)
    return waited


def client_for(script: Script, **kwargs: object) -> Client:
    http = httpx2.Client(transport=httpx2.MockTransport(script), base_url="http://svc")
    return Client("http://svc", http_client=http, **kwargs)  # type: ignore[arg-type]


def test_429_then_200_is_retried_after_retry_after(sleeps: list[float]) -> None:
    script = Script(problem(429, "overloaded", headers={"Retry-After": "2"}), httpx2.Response(200, json=filter_body()))
    result = client_for(script, retries=RetryPolicy(retries=2, backoff=0.01)).filter(SRC, SRC)
    assert result.n_inliers == 2 and list(result.inliers) == [0, 2]
    assert len(script.requests) == 2
    assert len(sleeps) == 1 and sleeps[0] >= 2.0
    assert script.requests[0].content == script.requests[1].content  # the same body went again


def test_503_with_retry_after_is_honoured_then_raised_as_overloaded(sleeps: list[float]) -> None:
    script = Script(*[problem(503, "not-ready", "pool starting", {"Retry-After": "3"}) for _ in range(3)])
    with pytest.raises(Overloaded) as info:
        client_for(script, retries=2).filter(SRC, SRC)
    err = info.value
    assert err.status == 503 and err.type == BASE + "not-ready" and err.detail == "pool starting"
    assert err.retry_after == 3.0
    assert len(script.requests) == 3 and sleeps and all(s >= 3.0 for s in sleeps)


def test_retry_after_as_http_date(sleeps: list[float]) -> None:
    when = format_datetime(datetime.now(UTC) + timedelta(seconds=30), usegmt=True)
    script = Script(problem(503, "not-ready", headers={"Retry-After": when}), httpx2.Response(200, json=filter_body()))
    client_for(script).filter(SRC, SRC)
    assert len(sleeps) == 1 and 20.0 < sleeps[0] <= 31.0


def test_retry_after_over_the_limit_is_raised_at_once(sleeps: list[float]) -> None:
    script = Script(problem(429, "overloaded", headers={"Retry-After": "600"}))
    with pytest.raises(Overloaded) as info:
        client_for(script, retries=RetryPolicy(max_retry_after=60)).filter(SRC, SRC)
    assert info.value.retry_after == 600.0 and len(script.requests) == 1 and sleeps == []


def test_backoff_grows_with_jitter_and_is_capped() -> None:
    import random
    policy = RetryPolicy(retries=10, backoff=1.0, max_backoff=5.0)
    rng = random.Random(0)
    for retry, ceiling in enumerate([1.0, 2.0, 4.0, 5.0, 5.0]):
        waits = {policy.delay(retry, None, rng) for _ in range(20)}
        assert all(ceiling / 2 <= w <= ceiling for w in waits) and len(waits) > 1
    assert policy.delay(0, 7.0, rng) == 7.0  # Retry-After wins over a shorter backoff


@pytest.mark.parametrize(("status", "kind", "error"), [
    (413, "too-large", TooLarge), (422, "invalid-input", InvalidInput), (400, "invalid-body", InvalidInput),
    (415, "unsupported-format", InvalidInput), (504, "timeout", Timeout), (500, "internal", ApiError),
    (404, "not-found", ApiError),
])
def test_other_errors_are_never_retried(sleeps: list[float], status: int, kind: str, error: type) -> None:
    script = Script(problem(status, kind, "the detail"), httpx2.Response(200, json=filter_body()))
    with pytest.raises(error) as info:
        client_for(script, retries=5).filter(SRC, SRC)
    assert type(info.value) is error
    assert (info.value.status, info.value.type, info.value.detail) == (status, BASE + kind, "the detail")
    assert info.value.title == kind.title()
    assert len(script.requests) == 1 and sleeps == []


def test_error_without_problem_body(sleeps: list[float]) -> None:
    script = Script(httpx2.Response(502, content=b"<html>Bad Gateway</html>", headers={"content-type": "text/html"}))
    with pytest.raises(ApiError) as info:
        client_for(script).filter(SRC, SRC)
    assert info.value.status == 502 and info.value.type == "about:blank"
    assert info.value.title == "Bad Gateway" and "Bad Gateway" in info.value.detail


def test_malformed_success_bodies(sleeps: list[float]) -> None:
    script = Script(httpx2.Response(200, content=b"{not json", headers={"content-type": "application/json"}))
    with pytest.raises(MalformedResponse, match="not JSON"):
        client_for(script).filter(SRC, SRC)
    bad = filter_body()
    bad["inliers"] = [0, 7]
    script = Script(httpx2.Response(200, json=bad))
    with pytest.raises(MalformedResponse, match="inliers"):
        client_for(script).filter(SRC, SRC)
    bad = filter_body()
    del bad["transform"]
    with pytest.raises(MalformedResponse, match="transform"):
        client_for(Script(httpx2.Response(200, json=bad))).filter(SRC, SRC)
    with pytest.raises(MalformedResponse, match="neither .npy nor .flo"):
        client_for(Script(httpx2.Response(200, content=b"GIF89a"))).flow(np.zeros((4, 4), np.uint8),
                                                                        np.zeros((4, 4), np.uint8))


def test_connection_errors_are_retried_with_backoff(sleeps: list[float]) -> None:
    script = Script(httpx2.ConnectError("refused"), httpx2.RemoteProtocolError("dropped"),
                    httpx2.Response(200, json=filter_body()))
    result = client_for(script, retries=RetryPolicy(retries=3, backoff=0.5)).filter(SRC, SRC)
    assert result.converged and len(script.requests) == 3
    assert 0.25 <= sleeps[0] <= 0.5 and 0.5 <= sleeps[1] <= 1.0


def test_connection_errors_exhaust_the_retries(sleeps: list[float]) -> None:
    script = Script(*[httpx2.ConnectError("refused") for _ in range(3)])
    with pytest.raises(Unreachable, match="refused") as info:
        client_for(script, retries=2).filter(SRC, SRC)
    assert info.value.status is None and len(script.requests) == 3 and len(sleeps) == 2
    assert isinstance(info.value.__cause__, httpx2.ConnectError)


def test_read_timeout_is_not_retried(sleeps: list[float]) -> None:
    script = Script(httpx2.ReadTimeout("slow"), httpx2.Response(200, json=filter_body()))
    with pytest.raises(Timeout, match="timeout") as info:
        client_for(script, retries=3).filter(SRC, SRC)
    assert info.value.status is None and len(script.requests) == 1 and sleeps == []


def test_explicit_timeout_goes_with_every_request() -> None:
    seen: list[dict] = []

    def answer(request: httpx2.Request) -> httpx2.Response:
        seen.append(request.extensions["timeout"])
        return httpx2.Response(200, json=filter_body())
    client_for(Script(answer), timeout=httpx2.Timeout(300.0, connect=2.0)).filter(SRC, SRC)
    assert seen[0]["read"] == 300.0 and seen[0]["connect"] == 2.0
    with Client("http://svc") as own:
        assert own.timeout.read == 120.0  # our own pool: longer than httpx's 5 s default


def test_bad_arguments_fail_before_sending() -> None:
    script = Script()
    client = client_for(script)
    with pytest.raises(ValueError, match=r"`src` must have shape"):
        client.filter([[1.0, 2.0, 3.0, 4.0]], [[1.0, 2.0, 3.0, 4.0]])
    with pytest.raises(ValueError, match="`dst` must hold only finite"):
        client.filter(SRC, [[0.0, np.nan]] * 3)
    with pytest.raises(ValueError, match="'npy' or 'flo'"):
        client.flow(b"a", b"b", format="png")
    with pytest.raises(TypeError, match="`image_a` must be"):
        client.match(3.5, b"b")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="base_url"):
        Client("localhost:8000")
    with pytest.raises(ValueError, match="retries"):
        Client("http://svc", retries=-1)
    with pytest.raises(TypeError, match="httpx2.Client"):
        Client("http://svc", http_client=httpx2.AsyncClient(transport=httpx2.MockTransport(script)))  # type: ignore[arg-type]
    assert script.requests == []


def test_async_client_retries_and_parses_errors(sleeps: list[float]) -> None:
    script = Script(problem(429, "overloaded", headers={"Retry-After": "1"}), httpx2.ConnectError("refused"),
                    httpx2.Response(200, json=filter_body()), problem(413, "too-large", "3 MB over"))

    async def run() -> None:
        http = httpx2.AsyncClient(transport=httpx2.MockTransport(script))
        async with AsyncClient("http://svc", http_client=http, retries=3) as client:
            result = await client.filter(SRC, SRC)
            assert result.n_inliers == 2
            with pytest.raises(TooLarge, match="3 MB over"):
                await client.filter(SRC, SRC)
        await http.aclose()
    asyncio.run(run())
    assert len(script.requests) == 4 and len(sleeps) == 2 and sleeps[0] >= 1.0


def test_health_reports_not_ready_without_retrying(sleeps: list[float]) -> None:
    script = Script(httpx2.Response(200, json={"status": "ok"}),
                    problem(503, "not-ready", "the compute pool is not ready", {"Retry-After": "1"}))
    health = client_for(script, retries=3).health()
    assert health.live and not health.ready and health.detail["status"] == 503
    assert [r.url.path for r in script.requests] == ["/livez", "/readyz"] and sleeps == []
    with pytest.raises(Unreachable):
        client_for(Script(httpx2.ConnectError("refused"))).health()


def test_retry_policy_is_validated() -> None:
    with pytest.raises(ValueError, match="`backoff`"):
        RetryPolicy(backoff=-1.0)
    with pytest.raises(ValueError, match="`retries`"):
        RetryPolicy(retries=True)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="`timeout`"):
        Client("http://svc", timeout=0)


def match_body() -> dict:
    return {"n_matches": 2, "n_inliers": 1, "src": [[0.0, 0.0], [1.0, 1.0]], "dst": [[1.0, 0.0], [5.0, 5.0]],
            "inliers": [0], "scores": [0.9, 0.0], "transform": KernelWarp.identity(2).to_dict(), "converged": True,
            "reason": None, "seed": 0, "timings_ms": {"features": 1.0}}


def test_match_many_keeps_exactly_concurrency_requests_in_flight() -> None:
    import threading

    lock = threading.Lock()
    state = {"now": 0, "most": 0, "seen": 0}
    barrier = threading.Barrier(3, timeout=30)  # the first 3 requests only go on once all 3 are in flight

    def answer(request: httpx2.Request) -> httpx2.Response:
        with lock:
            state["now"] += 1
            state["most"] = max(state["most"], state["now"])
            state["seen"] += 1
            first = state["seen"] <= 3
        if first:
            barrier.wait()
        with lock:
            state["now"] -= 1
        if b"broken" in request.content:
            return problem(400, "undecodable-image", "image_a cannot be decoded")
        return httpx2.Response(200, json=match_body())

    http = httpx2.Client(transport=httpx2.MockTransport(answer))
    image = np.zeros((4, 4), np.uint8)
    pairs = [(image, image)] * 9 + [(b"broken", image)]
    with Client("http://svc", http_client=http) as client:
        outcomes = list(client.match_many(pairs, concurrency=3, progress=False))
    assert state["most"] == 3 and state["seen"] == 10
    assert sorted(o.key for o in outcomes) == list(range(10))
    failed = [o for o in outcomes if not o.ok]
    assert [o.key for o in failed] == [9] and isinstance(failed[0].error, InvalidInput)
    assert all(o.result.n_inliers == 1 for o in outcomes if o.ok)


def test_async_match_many_bounds_in_flight_requests() -> None:
    state = {"now": 0, "most": 0}

    async def answer(request: httpx2.Request) -> httpx2.Response:
        state["now"] += 1
        state["most"] = max(state["most"], state["now"])
        await asyncio.sleep(0)  # let the other tasks run
        await asyncio.sleep(0)
        state["now"] -= 1
        return httpx2.Response(200, json=match_body())

    async def run() -> list:
        http = httpx2.AsyncClient(transport=httpx2.MockTransport(answer))
        image = np.zeros((4, 4), np.uint8)
        seen: list[tuple[int, int | None]] = []
        async with AsyncClient("http://svc", http_client=http) as client:
            outcomes = [o async for o in client.match_many(((image, image) for _ in range(7)), concurrency=2,
                                                           progress=lambda d, t: seen.append((d, t)))]
        await http.aclose()
        assert seen == [(i, None) for i in range(1, 8)]  # a generator has no length
        return outcomes

    outcomes = asyncio.run(run())
    assert sorted(o.key for o in outcomes) == list(range(7)) and all(o.ok for o in outcomes)
    assert 1 <= state["most"] <= 2
