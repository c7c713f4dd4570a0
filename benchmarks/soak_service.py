"""Soak of ``reglib serve``: N minutes at 1.5x its measured capacity, with workers killed (not run by CI).

Starts ``reglib serve`` on 127.0.0.1 (JSON logs to a temporary file) and, in the same run:

1. measures its capacity: closed loop, ``2 x workers`` clients, the same request mix as the soak,
   for ``--capacity-seconds``; capacity = answers per second;
2. offers ``--load`` (1.5) times that rate for ``--minutes``, open loop (Poisson arrivals, so a
   slow answer does not slow the offer), from ``--client-procs`` client processes; the mix is
   60 % ``/v1/match`` on two 768x512 JPEGs, 20 % ``/v1/filter`` on 300 matches, and 20 % invalid
   requests (bad JSON 400, NaN points 422, an undecodable image 400, a wrong media type 415);
3. SIGKILLs one worker (at random) every ``--kill-every`` seconds (0: never);
4. samples the RSS of the server process and of each of its children every ``--rss-every`` seconds.

It prints the statuses per minute, p50 / p99 of the accepted requests (every answer but 429 and
503), the 5xx other than 503, the RSS of every process (at ``--rss-reference-min`` minutes, or once
a fresh worker is 60 s old; its largest after that; its last), and the count of requests that got
no answer at all (transport error or client timeout; must be 0). The RSS picture goes to
``benchmarks/figures/soak_rss.png`` (``--figure``).

Run:  .venv/bin/python benchmarks/soak_service.py [--minutes 30] [--workers 2] [--kill-every 150]
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import httpx2
import numpy as np
import skimage.data

CLIENT_TIMEOUT_S = 120.0
LOST = -1  # no answer: transport error or client timeout
WARM_S = 60.0  # a fresh worker's RSS is compared from this age on (it grows on its first requests)


# -- the request mix ---------------------------------------------------------------------------------

def jpeg_pair(width: int = 768, height: int = 512) -> tuple[bytes, bytes]:
    a = cv2.resize(skimage.data.astronaut(), (width, height), interpolation=cv2.INTER_AREA)
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    b = cv2.remap(a, cols - 9.0 - 5.0 * np.sin(rows / 90.0), rows + 6.0 - 3.0 * np.cos(cols / 110.0),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    enc = [cv2.imencode(".jpg", cv2.cvtColor(im, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()
           for im in (a, b)]
    return enc[0], enc[1]


def points_body(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 300, (300, 2))
    dst = src + [5.0, -3.0] + 4.0 * np.sin(src[:, ::-1] / 60.0)
    dst[:60] = rng.uniform(0, 300, (60, 2))
    return {"src": src.tolist(), "dst": dst.tolist(), "seed": seed}


KINDS = ("match", "filter", "bad-json", "nan-points", "bad-image", "bad-media")
WEIGHTS = (0.60, 0.20, 0.05, 0.05, 0.05, 0.05)


class Mix:
    """Builds each kind of request; ``send(http, kind)`` -> status code (or LOST)."""

    def __init__(self) -> None:
        a, b = jpeg_pair()
        self.files = {"image_a": ("a.jpg", a, "image/jpeg"), "image_b": ("b.jpg", b, "image/jpeg")}
        self.bad_files = {"image_a": ("a.jpg", a[:2000], "image/jpeg"), "image_b": ("b.jpg", b, "image/jpeg")}
        self.filter_bodies = [json.dumps(points_body(s)).encode() for s in range(4)]
        nan = points_body(0)
        nan["src"][3][0] = "NaN"
        self.nan_body = json.dumps(nan).replace('"NaN"', "NaN").encode()

    def send(self, http: httpx2.Client, kind: str, k: int) -> int:
        json_type = {"Content-Type": "application/json"}
        try:
            if kind == "match":
                r = http.post("/v1/match", files=self.files, data={"dense": "false", "seed": "0"})
            elif kind == "filter":
                r = http.post("/v1/filter", content=self.filter_bodies[k % 4], headers=json_type)
            elif kind == "bad-json":
                r = http.post("/v1/filter", content=b'{"src": [[0, 0]', headers=json_type)
            elif kind == "nan-points":
                r = http.post("/v1/filter", content=self.nan_body, headers=json_type)
            elif kind == "bad-image":
                r = http.post("/v1/match", files=self.bad_files)
            else:
                r = http.post("/v1/filter", content=b"src=1", headers={"Content-Type": "text/plain"})
            return r.status_code
        except httpx2.HTTPError:
            return LOST


# -- the server --------------------------------------------------------------------------------------

def start_server(workers: int, queue: int, log_path: str) -> tuple[subprocess.Popen, str]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "REGLIB_QUEUE_SIZE": str(queue), "REGLIB_COMPUTE_TIMEOUT_S": "60",
           "REGLIB_LOG_FORMAT": "json"}
    log = open(log_path, "wb")  # noqa: SIM115 - the server writes to it for the whole run
    proc = subprocess.Popen([sys.executable, "-m", "reglib.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
                             "--workers", str(workers), "--log-level", "warning"],
                            env=env, stdout=subprocess.DEVNULL, stderr=log)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"the service exited at start: {Path(log_path).read_text()[-2000:]}")
        try:
            if httpx2.get(url + "/readyz", timeout=2).status_code == 200:
                return proc, url
        except httpx2.TransportError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise SystemExit("the service did not become ready")


def children(pid: int) -> list[int]:
    out: list[int] = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children", encoding="ascii") as f:
                out += [int(p) for p in f.read().split()]
    except OSError:
        pass
    return sorted(set(out))


def cmdline(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read()
    except OSError:
        return b""


def worker_pids(server_pid: int) -> list[int]:
    return [p for p in children(server_pid) if b"spawn_main" in cmdline(p) and b"resource_tracker" not in cmdline(p)]


def rss_bytes(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


# -- load --------------------------------------------------------------------------------------------

def closed_loop(url: str, mix: Mix, clients: int, seconds: float) -> float:
    """Answers per second with ``clients`` back-to-back clients."""
    count = Counter()
    lock = threading.Lock()
    stop_at = time.monotonic() + seconds
    kinds = random.Random(1).choices(KINDS, WEIGHTS, k=100_000)

    def client(c: int) -> None:
        with httpx2.Client(base_url=url, timeout=CLIENT_TIMEOUT_S) as http:
            i = c
            while time.monotonic() < stop_at:
                status = mix.send(http, kinds[i % len(kinds)], i)
                i += clients
                with lock:
                    count[status] += 1

    start = time.monotonic()
    with ThreadPoolExecutor(clients) as pool:
        list(pool.map(client, range(clients)))
    wall = time.monotonic() - start
    answered = sum(n for status, n in count.items() if status not in (LOST, 429, 503))
    print(f"capacity run: {clients} clients, {wall:.0f} s, statuses {dict(sorted(count.items()))}")
    return answered / wall


def open_loop_process(url: str, rate: float, seconds: float, seed: int, t0: float, conn) -> None:
    """One client process: Poisson arrivals at ``rate`` per second; sends back (t, kind, status, latency)."""
    mix = Mix()
    rng = random.Random(seed)
    local = threading.local()
    records: list[tuple[float, str, int, float]] = []
    lock = threading.Lock()

    def one(kind: str, k: int, due: float) -> None:
        http = getattr(local, "http", None)
        if http is None:
            http = local.http = httpx2.Client(base_url=url, timeout=CLIENT_TIMEOUT_S)
        start = time.time()
        status = mix.send(http, kind, k)
        with lock:
            records.append((due - t0, kind, status, time.time() - start))

    with ThreadPoolExecutor(64) as threads:
        due = max(time.time(), t0)
        end = t0 + seconds
        k = 0
        while True:
            due += rng.expovariate(rate)
            if due >= end:
                break
            delay = due - time.time()
            if delay > 0:
                time.sleep(delay)
            threads.submit(one, rng.choices(KINDS, WEIGHTS)[0], k, due)
            k += 1
    conn.send(records)
    conn.close()


# -- report ------------------------------------------------------------------------------------------

def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) * 1e3 if values else float("nan")


def report(records, kills, rss, roles: dict[int, str], minutes: float, ref_min: float, figure: Path) -> None:
    print("\n| minute | sent | 200 | 400 | 413 | 415 | 422 | 429 | 503 | 500 | 504 | other | no answer | kills |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    per_minute: dict[int, Counter] = defaultdict(Counter)
    for t, _kind, status, _lat in records:
        per_minute[int(t // 60)][status] += 1
    kills_per_minute = Counter(int(t // 60) for t, _pid in kills)
    shown = (200, 400, 413, 415, 422, 429, 503, 500, 504)
    for minute in range(int(np.ceil(minutes))):
        c = per_minute[minute]
        other = sum(n for s, n in c.items() if s not in shown and s != LOST)
        print(f"| {minute} | {sum(c.values())} | " + " | ".join(str(c[s]) for s in shown)
              + f" | {other} | {c[LOST]} | {kills_per_minute[minute]} |")
    total = Counter(status for _t, _k, status, _l in records)
    print(f"| all | {sum(total.values())} | " + " | ".join(str(total[s]) for s in shown)
          + f" | {sum(n for s, n in total.items() if s not in shown and s != LOST)} | {total[LOST]} | {len(kills)} |")

    accepted = [lat for _t, _k, s, lat in records if s not in (LOST, 429, 503)]
    match_ok = [lat for _t, k, s, lat in records if k == "match" and s == 200]
    print("\n| accepted requests | n | p50 ms | p99 ms |\n| --- | --- | --- | --- |")
    print(f"| all (every answer but 429 / 503) | {len(accepted)} | {pct(accepted, 50):.0f} | {pct(accepted, 99):.0f} |")
    print(f"| /v1/match 200 | {len(match_ok)} | {pct(match_ok, 50):.0f} | {pct(match_ok, 99):.0f} |")

    fives = [(t, k, s) for t, k, s, _l in records if s >= 500 and s != 503]
    print(f"\n5xx other than 503: {len(fives)}" + (f" (first: {fives[:5]})" if fives else ""))
    print(f"requests with no answer (transport error or {CLIENT_TIMEOUT_S:.0f} s timeout): {total[LOST]}")

    print(f"\n| process | first seen s | RSS at {ref_min:g} min (or {WARM_S:.0f} s old) MiB | max after MiB | last MiB "
          "| max change |")
    print("| --- | --- | --- | --- | --- | --- |")
    series: dict[int, list[tuple[float, int]]] = defaultdict(list)
    for t, pid, value in rss:
        series[pid].append((t, value))
    for pid, points in sorted(series.items(), key=lambda kv: kv[1][0][0]):
        role = roles[pid] if roles[pid] == "server" else f"{roles[pid]} {pid}"
        first = points[0][0]
        # the reference: at ref_min minutes into the run, and at least WARM_S after the process appeared
        later = [(t, v) for t, v in points if t >= max(ref_min * 60, first + WARM_S)]
        if len(later) < 2:
            print(f"| {role} | {first:.0f} | - | - | {points[-1][1] / 2**20:.0f} | (not alive long enough) |")
            continue
        ref = later[0][1]
        peak = max(v for _t, v in later)
        print(f"| {role} | {first:.0f} | {ref / 2**20:.0f} | {peak / 2**20:.0f} | {points[-1][1] / 2**20:.0f} | "
              f"{100 * (peak / ref - 1):+.1f} % |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for pid, points in sorted(series.items()):
        t, v = zip(*points, strict=True)
        label = roles[pid] if roles[pid] == "server" else f"{roles[pid]} {pid}"
        ax.plot(np.asarray(t) / 60, np.asarray(v) / 2**20, label=label, lw=1.5 if roles[pid] == "server" else 1)
    for t, _pid in kills:
        ax.axvline(t / 60, color="red", lw=0.8, ls="--")
    ax.set_xlabel("minutes (dashed: a worker killed)")
    ax.set_ylabel("RSS (MiB)")
    ax.set_title(f"reglib serve under {minutes:g} min of load: RSS of every process")
    ax.legend(fontsize=7, ncol=3, loc="lower right")
    fig.tight_layout()
    figure.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(figure, dpi=110)
    print(f"\nRSS picture: {figure}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--queue", type=int, default=4)
    parser.add_argument("--load", type=float, default=1.5, help="offered rate / measured capacity")
    parser.add_argument("--client-procs", type=int, default=3)
    parser.add_argument("--capacity-seconds", type=float, default=30.0)
    parser.add_argument("--kill-every", type=float, default=150.0, help="seconds between worker kills (0: none)")
    parser.add_argument("--rss-every", type=float, default=5.0)
    parser.add_argument("--rss-reference-min", type=float, default=5.0)
    parser.add_argument("--figure", type=Path, default=Path(__file__).parent / "figures" / "soak_rss.png")
    args = parser.parse_args()

    cv2.setNumThreads(1)
    log_path = tempfile.mktemp(prefix="reglib-soak-", suffix=".log")
    proc, url = start_server(args.workers, args.queue, log_path)
    print(f"reglib serve: {args.workers} workers, queue {args.queue}, {os.cpu_count()} CPUs (shared), "
          f"log {log_path}")
    try:
        mix = Mix()
        with httpx2.Client(base_url=url, timeout=CLIENT_TIMEOUT_S) as http:  # warm every worker
            for k in range(2 * args.workers):
                mix.send(http, "match", k)
        capacity = closed_loop(url, mix, 2 * args.workers, args.capacity_seconds)
        rate = args.load * capacity
        kill_text = f"a worker killed every {args.kill_every:g} s" if args.kill_every else "no kills"
        print(f"capacity {capacity:.2f} answers/s; offering {rate:.2f} requests/s ({args.load:g}x) for "
              f"{args.minutes:g} min from {args.client_procs} processes; {kill_text}")

        seconds = args.minutes * 60
        t0 = time.time() + 2.0
        ctx = multiprocessing.get_context("spawn")
        pipes, procs = [], []
        for i in range(args.client_procs):
            parent, child = ctx.Pipe(duplex=False)
            p = ctx.Process(target=open_loop_process, args=(url, rate / args.client_procs, seconds, 100 + i, t0, child))
            p.start()
            child.close()
            pipes.append(parent)
            procs.append(p)

        kills: list[tuple[float, int]] = []
        rss: list[tuple[float, int, int]] = []
        roles: dict[int, str] = {proc.pid: "server"}
        rng = random.Random(7)
        next_kill = t0 + args.kill_every if args.kill_every else float("inf")
        next_rss = t0
        while time.time() < t0 + seconds:
            now = time.time()
            if now >= next_rss:
                for pid in [proc.pid, *children(proc.pid)]:
                    if pid not in roles:
                        roles[pid] = "resource tracker" if b"resource_tracker" in cmdline(pid) else "worker"
                    value = rss_bytes(pid)
                    if value is not None:
                        rss.append((now - t0, pid, value))
                next_rss += args.rss_every
            if now >= next_kill:
                pids = worker_pids(proc.pid)
                if pids:
                    victim = rng.choice(pids)
                    os.kill(victim, signal.SIGKILL)
                    kills.append((now - t0, victim))
                next_kill += args.kill_every
            time.sleep(0.2)
        records = []
        for parent in pipes:
            records += parent.recv()  # each process ends within CLIENT_TIMEOUT_S of the end
        for p in procs:
            p.join(timeout=30)
        records.sort()
        alive = httpx2.get(url + "/readyz", timeout=10).status_code
        report(records, kills, rss, roles, args.minutes, args.rss_reference_min, args.figure)
        with open(log_path, encoding="utf-8") as f:
            lines = [json.loads(line) for line in f if line.startswith("{")]
        levels = Counter(line["level"] for line in lines)
        print(f"server log lines by level: {dict(levels)}; /readyz at the end: {alive}")
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            status = proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            status = proc.wait()
        print(f"server exit status after SIGTERM: {status}")


if __name__ == "__main__":
    main()
