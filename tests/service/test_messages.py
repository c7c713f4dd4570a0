"""What the service says to a new user: a misspelled field answered with the nearest name, sizes in
binary units, a start-up that says whether API keys are on, and ``reglib serve`` on a busy port."""
from __future__ import annotations

import re
import socket
import subprocess
import sys

import pytest

from service import problems as P
from service.units import human_bytes, size_over_limit

from ..conftest import ROOT, _environment


def _post_match(client, png_pair, **fields):
    files = {"image_a": ("a.png", png_pair[0], "image/png"), "image_b": ("b.png", png_pair[1], "image/png")}
    return client.post("/v1/match", files=files, data=fields)


def test_a_misspelled_field_names_the_nearest_one_and_not_all_of_them(client, png_pair):
    r = _post_match(client, png_pair, ratoi="0.9")
    assert r.status_code == 422 and r.json()["type"] == P.INVALID_INPUT
    detail = r.json()["detail"]
    assert "`ratoi`" in detail and "did you mean `ratio`?" in detail
    assert "max_keypoints" not in detail and "features" not in detail  # not the whole list of fields


def test_a_field_like_no_other_lists_the_fields(client, png_pair):
    detail = _post_match(client, png_pair, zzzzzz="1").json()["detail"]
    assert "unknown field `zzzzzz`; the fields of /v1/match are [" in detail and "'ratio'" in detail


def test_an_oversized_body_is_told_in_binary_units(client, settings):
    body = b" " * (settings.max_json_bytes + 5 * 1024 * 1024)
    r = client.post("/v1/filter", content=body, headers={"content-type": "application/json"})
    assert r.status_code == 413
    limit = human_bytes(settings.max_json_bytes)
    assert r.json()["detail"] == f"the body is 7 MiB, over the limit of {limit}" and limit == "2 MiB"


def test_sizes_read_in_binary_units():
    assert [human_bytes(n) for n in (0, 1023, 1024, 33554432, 96063136, 9496860672)] == [
        "0 bytes", "1023 bytes", "1 KiB", "32 MiB", "91.6 MiB", "8.84 GiB"]
    assert size_over_limit(96063136, 33554432) == "91.6 MiB, over the limit of 32 MiB"


def test_serve_on_a_busy_port_is_one_line_and_exit_2():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        done = subprocess.run([sys.executable, "-m", "reglib.cli", "serve", "--port", str(port), "--workers", "1",
                               "--log-level", "info"], cwd=ROOT, env=_environment(None), capture_output=True,
                              text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [f"reglib serve: error: cannot listen on 127.0.0.1:{port}: the port is in "
                                        "use (another server?); choose another with --port"]
    assert "work pool" not in done.stdout  # refused before the pool started


@pytest.mark.slow
def test_start_up_says_the_memory_cap_in_units_and_that_keys_are_on(start_live_server, tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("first-test-key-0123\n# a comment\nsecond-test-key-4567\n")
    server = start_live_server(workers=1, log_level="info",
                               env={"REGLIB_API_KEYS_FILE": str(keys), "REGLIB_WORKER_MAX_MEMORY": str(3 << 30)})
    log = server.output()
    assert "worker memory cap 3 GiB" in log and not re.search(r"\d{6,} bytes", log)
    assert "API keys on (2 keys" in log and "first-test-key" not in log
