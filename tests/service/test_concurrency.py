"""8 parallel clients for a bounded time against a real uvicorn on 127.0.0.1.

Only 200, 429 and 503 may come back (429/503 as problem+json with Retry-After), and every 200
must equal the library's answer for that request.
"""
from __future__ import annotations

import json
import threading
import time
from collections import Counter

import httpx2
import numpy as np
import pytest

import reglib
from reglib.io import read_image

pytestmark = pytest.mark.slow

CLIENTS = 8
SECONDS = 8.0


def variants() -> list[tuple[dict, dict]]:
    out = []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        src = rng.uniform(0, 300, (150 + 50 * seed, 2))
        dst = src + [5.0, -3.0] + 4.0 * np.sin(src[:, ::-1] / 60.0)
        dst[: 40] = rng.uniform(0, 300, (40, 2))
        body = {"src": src.tolist(), "dst": dst.tolist(), "seed": seed}
        expected = json.loads(json.dumps(reglib.filter_matches(src, dst, rng=seed).to_dict()))
        out.append((body, expected))
    return out


def test_eight_clients(live_server, png_pair):
    cases = variants()
    a = read_image(png_pair[0])
    b = read_image(png_pair[1])
    match_expected = reglib.match_images(a, b, options={"dense": False, "max_keypoints": 500,
                                                        "max_pixels": 2_000_000}, rng=0)
    files = {"image_a": ("a.png", png_pair[0], "image/png"), "image_b": ("b.png", png_pair[1], "image/png")}
    statuses: Counter[int] = Counter()
    wrong: list[str] = []
    lock = threading.Lock()
    stop_at = time.monotonic() + SECONDS

    def client(k: int) -> None:
        with httpx2.Client(base_url=live_server.url, timeout=60) as http:
            i = 0
            while time.monotonic() < stop_at:
                i += 1
                if (k + i) % 5 == 0:
                    r = http.post("/v1/match", files=files, data={"dense": "false", "max_keypoints": "500"})
                    ok = r.status_code != 200 or r.json()["inliers"] == np.flatnonzero(match_expected.inliers).tolist()
                else:
                    body, expected = cases[(k + i) % len(cases)]
                    r = http.post("/v1/filter", json=body)
                    if r.status_code == 200:
                        got = r.json()
                        got.pop("timings_ms")
                        ok = got["inliers"] == expected["inliers"] and got["transform"] == expected["transform"] \
                            and np.allclose(got["scores"], expected["scores"], rtol=1e-9, atol=0)
                    else:
                        ok = True
                if r.status_code in (429, 503):
                    ok = r.headers["content-type"].startswith("application/problem+json") and "retry-after" in r.headers
                with lock:
                    statuses[r.status_code] += 1
                    if not ok:
                        wrong.append(f"{r.request.url.path} {r.status_code}: {r.text[:200]}")

    threads = [threading.Thread(target=client, args=(k,)) for k in range(CLIENTS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=SECONDS + 120)
    assert not any(t.is_alive() for t in threads)
    assert set(statuses) <= {200, 429, 503}, statuses
    assert statuses[200] > 0, statuses
    assert not wrong, wrong[:3]
    # the server is still whole afterwards
    assert httpx2.get(live_server.url + "/readyz", timeout=10).status_code == 200
    metrics = httpx2.get(live_server.url + "/metrics", timeout=10).text
    assert "reglib_http_requests_total" in metrics
