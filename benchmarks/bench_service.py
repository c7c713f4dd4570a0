"""Service overhead, throughput and overload behaviour of ``/v1/match`` (not run by CI).

Starts ``reglib serve`` on 127.0.0.1 and, for two 768x512 JPEGs (scikit-image's bundled astronaut,
and the same under a known smooth warp), measures in the same run:

1. p50 / p99 latency of ``/v1/match`` with one client, against bare ``reglib.match_images`` (decode
   included) in this process, with the same options and seed;
2. throughput with 1, 2, 4 and 8 concurrent clients;
3. 2x overload: twice as many clients as the pool + queue admit, counting 200 / 429 / 503 / other
   and the p99 of the accepted requests.

Run:  .venv/bin/python benchmarks/bench_service.py [--workers 2] [--repeats 20] [--seconds 20] [--dense]
"""
from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter

import cv2
import httpx2
import numpy as np
import skimage.data

import reglib
from reglib.io import read_image


def jpeg_pair(width: int = 768, height: int = 512) -> tuple[bytes, bytes]:
    a = cv2.resize(skimage.data.astronaut(), (width, height), interpolation=cv2.INTER_AREA)
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    b = cv2.remap(a, cols - 9.0 - 5.0 * np.sin(rows / 90.0), rows + 6.0 - 3.0 * np.cos(cols / 110.0),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    enc = [cv2.imencode(".jpg", cv2.cvtColor(im, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()
           for im in (a, b)]
    return enc[0], enc[1]


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


def start_server(workers: int, queue: int) -> tuple[subprocess.Popen, str, object]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    log = tempfile.TemporaryFile()
    env = {**os.environ, "REGLIB_QUEUE_SIZE": str(queue), "REGLIB_COMPUTE_TIMEOUT_S": "300"}
    proc = subprocess.Popen([sys.executable, "-m", "reglib.cli", "serve", "--port", str(port), "--workers",
                             str(workers), "--log-level", "warning"], env=env, stdout=subprocess.DEVNULL, stderr=log)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            if httpx2.get(url + "/readyz", timeout=2).status_code == 200:
                return proc, url, log
        except httpx2.TransportError:
            time.sleep(0.2)
    proc.kill()
    raise SystemExit("the service did not become ready")


def load(url: str, files: dict, data: dict, clients: int, seconds: float) -> tuple[Counter, list[float], float]:
    statuses: Counter[int] = Counter()
    accepted: list[float] = []
    lock = threading.Lock()
    stop_at = time.monotonic() + seconds

    def run() -> None:
        with httpx2.Client(base_url=url, timeout=300) as http:
            while time.monotonic() < stop_at:
                t0 = time.perf_counter()
                try:
                    code = http.post("/v1/match", files=files, data=data).status_code
                except httpx2.TransportError:
                    code = -1
                dt = time.perf_counter() - t0
                with lock:
                    statuses[code] += 1
                    if code == 200:
                        accepted.append(dt)
                if code in (429, 503):
                    time.sleep(0.05)

    start = time.perf_counter()
    threads = [threading.Thread(target=run) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return statuses, accepted, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--queue", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--dense", action="store_true", help="with the dense stage (much slower)")
    args = parser.parse_args()

    cv2.setNumThreads(1)  # as in the service's workers
    a_bytes, b_bytes = jpeg_pair()
    files = {"image_a": ("a.jpg", a_bytes, "image/jpeg"), "image_b": ("b.jpg", b_bytes, "image/jpeg")}
    data = {"dense": str(args.dense).lower(), "seed": "0"}
    print(f"reglib {reglib.__version__}, two 768x512 JPEGs, dense={args.dense}, seed 0, "
          f"{args.workers} workers, queue {args.queue}, {os.cpu_count()} CPUs")

    proc, url, log = start_server(args.workers, args.queue)
    try:
        with httpx2.Client(base_url=url, timeout=300) as http:
            http.post("/v1/match", files=files, data=data)  # warm both sides
            reglib.match_images(read_image(a_bytes), read_image(b_bytes), options={"dense": args.dense}, rng=0)
            lib, svc, server = [], [], []
            for _ in range(args.repeats):  # interleaved so drifts in machine load hit both alike
                t0 = time.perf_counter()
                m = reglib.match_images(read_image(a_bytes), read_image(b_bytes), options={"dense": args.dense}, rng=0)
                lib.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                r = http.post("/v1/match", files=files, data=data)
                svc.append(time.perf_counter() - t0)
                assert r.status_code == 200 and r.json()["n_inliers"] == m.n_inliers, r.text[:200]
                stages = r.json()["timings_ms"]
                server.append((stages["total"] + stages.get("decode", 0.0)) / 1e3)
        print("\n| latency (1 client) | p50 ms | p99 ms |\n| --- | --- | --- |")
        print(f"| library match_images | {percentile(lib, 50) * 1e3:.0f} | {percentile(lib, 99) * 1e3:.0f} |")
        print(f"| service /v1/match | {percentile(svc, 50) * 1e3:.0f} | {percentile(svc, 99) * 1e3:.0f} |")
        print(f"| overhead | {100 * (percentile(svc, 50) / percentile(lib, 50) - 1):+.1f} % | "
              f"{100 * (percentile(svc, 99) / percentile(lib, 99) - 1):+.1f} % |")
        print(f"| (the worker's own decode + match_images time, from the answer) | "
              f"{percentile(server, 50) * 1e3:.0f} | {percentile(server, 99) * 1e3:.0f} |")

        print("\n| clients | requests/s | p50 ms | p99 ms | statuses |\n| --- | --- | --- | --- | --- |")
        for clients in (1, 2, 4, 8):
            statuses, accepted, wall = load(url, files, data, clients, args.seconds)
            print(f"| {clients} | {len(accepted) / wall:.2f} | {percentile(accepted, 50) * 1e3:.0f} | "
                  f"{percentile(accepted, 99) * 1e3:.0f} | {dict(sorted(statuses.items()))} |")

        over = 2 * (args.workers + args.queue)
        statuses, accepted, wall = load(url, files, data, over, args.seconds)
        alive = httpx2.get(url + "/readyz", timeout=10).status_code
        print(f"\n2x overload: {over} clients for {args.seconds:.0f} s against {args.workers} workers + "
              f"{args.queue} queue places: statuses {dict(sorted(statuses.items()))}, "
              f"{len(accepted) / wall:.2f} accepted/s, accepted p50 {percentile(accepted, 50) * 1e3:.0f} ms, "
              f"p99 {percentile(accepted, 99) * 1e3:.0f} ms; /readyz afterwards {alive}")
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


if __name__ == "__main__":
    main()
