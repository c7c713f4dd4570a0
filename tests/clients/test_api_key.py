"""The client's ``api_key=`` (and ``$REGLIB_API_KEY``) against a real uvicorn on 127.0.0.1 that has API keys."""
from __future__ import annotations

import asyncio
import re
from collections.abc import Iterator

import httpx2
import numpy as np
import pytest

from reglib_client import ApiError, AsyncClient, Client, RetryPolicy, Unauthorized

from ..conftest import LiveServer

KEY = "9d7c5b3a-client-test-key"
KEY_ID = "bc012fe16a04"  # the first 12 hex digits of sha256(KEY): how the service names this caller

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def base_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    keys = tmp_path_factory.mktemp("keyed") / "keys.txt"
    keys.write_text(f"# one caller\n{KEY}\n")
    env = {"REGLIB_WORKERS": "1", "REGLIB_QUEUE_SIZE": "4", "REGLIB_API_KEYS_FILE": str(keys), "REGLIB_API_KEY": None}
    server = LiveServer.uvicorn(env)
    try:
        yield server.wait_ready().url
    finally:
        server.stop()


def points() -> tuple[np.ndarray, np.ndarray]:
    src = np.random.default_rng(0).uniform(0, 300, (40, 2))
    return src, src + [3.0, 4.0]


def counted(url: str, name: str, label: str) -> float:
    """A counter of the service's /metrics (open to this loopback caller)."""
    m = re.search(rf"^{name}\{{{label}\}} (\S+)$", httpx2.get(url + "/metrics", timeout=10).text, re.M)
    return float(m.group(1)) if m else 0.0


def test_api_key_is_sent_with_every_request(base_url, monkeypatch):
    monkeypatch.delenv("REGLIB_API_KEY", raising=False)
    src, dst = points()
    before = counted(base_url, "reglib_key_requests_total", f'key="{KEY_ID}"')
    with Client(base_url, api_key=KEY, timeout=60.0) as client:
        assert client.health().ready
        result = client.filter(src, dst)
        assert result.converged and result.n_inliers == 40
        np.testing.assert_allclose(result.transform([[10.0, 20.0]]), [[13.0, 24.0]], atol=0.05)
        registered = client.register(src, dst, method="icp")
        assert np.abs(registered.registered - dst).max() < 1e-6
    assert counted(base_url, "reglib_key_requests_total", f'key="{KEY_ID}"') == before + 2
    assert "api_key" not in repr(client) and KEY not in repr(client)


def test_without_a_key_or_with_a_wrong_one_the_error_is_a_401_not_retried(base_url, monkeypatch):
    monkeypatch.delenv("REGLIB_API_KEY", raising=False)
    src, dst = points()
    for api_key, reason in ((None, "missing"), ("not-the-key", "wrong")):
        before = counted(base_url, "reglib_auth_failures_total", f'reason="{reason}"')
        with Client(base_url, api_key=api_key, retries=RetryPolicy(retries=3, backoff=0.01)) as client:
            with pytest.raises(ApiError) as info:
                client.filter(src, dst)
        assert info.value.status == 401 and info.value.type.endswith("/unauthorized")
        assert isinstance(info.value, Unauthorized)
        assert counted(base_url, "reglib_auth_failures_total", f'reason="{reason}"') == before + 1  # sent once


def test_the_key_comes_from_the_environment_unless_given(base_url, monkeypatch):
    src, dst = points()
    monkeypatch.setenv("REGLIB_API_KEY", KEY)
    with Client(base_url) as client:
        assert client.filter(src, dst).n_inliers == 40
    monkeypatch.setenv("REGLIB_API_KEY", "a-wrong-key")
    with Client(base_url, api_key=KEY) as client:  # given: it wins over the environment
        assert client.filter(src, dst).n_inliers == 40
    with Client(base_url, retries=0) as client, pytest.raises(ApiError) as info:
        client.filter(src, dst)
    assert info.value.status == 401


def test_the_async_client_sends_it_too(base_url, monkeypatch):
    monkeypatch.delenv("REGLIB_API_KEY", raising=False)
    src, dst = points()

    async def run() -> tuple[int, int | None]:
        async with AsyncClient(base_url, api_key=KEY) as client:
            kept = (await client.filter(src, dst)).n_inliers
        async with AsyncClient(base_url, retries=0) as client:
            try:
                await client.filter(src, dst)
            except ApiError as err:
                return kept, err.status
        return kept, None

    assert asyncio.run(run()) == (40, 401)


def test_a_key_that_cannot_be_a_header_is_refused_at_once(monkeypatch):
    monkeypatch.delenv("REGLIB_API_KEY", raising=False)
    for bad in ("", "two words", "caf\u00e9", 42):
        with pytest.raises(ValueError, match=r"^`api_key` must be one word of printable ASCII"):
            Client("http://127.0.0.1:9", api_key=bad)  # type: ignore[arg-type]
    monkeypatch.setenv("REGLIB_API_KEY", "Bearer abc")
    with pytest.raises(ValueError, match=r"^\$REGLIB_API_KEY must be one word"):
        AsyncClient("http://127.0.0.1:9")
    monkeypatch.setenv("REGLIB_API_KEY", "  ")
    Client("http://127.0.0.1:9").close()  # blank: no key
