"""The client over real HTTP: one uvicorn serving the app on 127.0.0.1, started and stopped here."""
from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from reglib_client import Client, InvalidInput, RetryPolicy, Unreachable, encode_png

from ..conftest import LiveServer
from .conftest import shifted_pair

START_LIMIT_S = 120.0  # the server must be ready within this; it is stopped in every case


@pytest.mark.slow
def test_client_against_a_real_uvicorn(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    server = LiveServer.uvicorn({"REGLIB_WORKERS": "1", "REGLIB_QUEUE_SIZE": "4"})
    base_url = server.url
    root = Path(__file__).resolve().parents[2]
    try:
        with Client(base_url, timeout=60.0, retries=RetryPolicy(retries=2, backoff=0.05)) as client:
            # readiness through the client itself (Unreachable while the server starts)
            deadline = time.monotonic() + START_LIMIT_S
            while True:
                assert server.proc.poll() is None, f"uvicorn exited early:\n{server.output()}"
                try:
                    if client.health().ready:
                        break
                except Unreachable:
                    pass
                assert time.monotonic() < deadline, f"not ready in time:\n{server.output()}"
                time.sleep(0.2)

            rng = np.random.default_rng(0)
            src = rng.uniform(0, 300, (40, 2))
            result = client.filter(src, src + [3.0, 4.0])
            assert result.converged and result.n_inliers == 40
            np.testing.assert_allclose(result.transform([[10.0, 20.0]]), [[13.0, 24.0]], atol=0.05)

            pair = shifted_pair(0)
            path_a = tmp_path / "a.png"
            path_a.write_bytes(encode_png(pair.a))
            match = client.match(path_a, pair.b)
            assert match.converged
            kept = match.src[match.inliers]
            assert np.abs(match.transform(kept) - (kept + pair.shift)).max() < 1.0

            with pytest.raises(InvalidInput) as info:
                client.match(path_a, pair.b, no_such_option=1)
            assert info.value.status == 422

        # The client README's example runs as written, against this server.
        readme = (root / "clients" / "python" / "README.md").read_text(encoding="utf-8")
        example = re.search(r"```python\n(.*?)```", readme, re.S)
        assert example is not None and "http://127.0.0.1:8000" in example.group(1)
        monkeypatch.chdir(tmp_path)  # where the example saves its bundle
        exec(compile(example.group(1).replace("http://127.0.0.1:8000", base_url), "README.md", "exec"), {})
        printed = capsys.readouterr().out
        assert "40 of 50 matches are true" in printed and "invalid-input" in printed
        assert "MatchResult(n_matches=" in printed and "features=" in printed and "(200, 280, 2)" in printed
        saved = sorted(p.name for p in (tmp_path / "out" / "pair-1").iterdir())
        assert saved == ["confidence.png", "flow.flo", "flow.png", "match.json", "overlay.png", "transform.json",
                         "warped.png"]
    finally:
        server.stop()

    # Nobody listens any more: real connection errors, retried, then Unreachable.
    with Client(base_url, retries=RetryPolicy(retries=1, backoff=0.01)) as client:
        with pytest.raises(Unreachable):
            client.filter(src, src)
