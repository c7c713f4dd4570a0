"""The Dockerfile cannot be built here; what it runs can be: its dependency step, its commands, its health check."""
from __future__ import annotations

import re
import shlex
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[3]
DOCKERFILE = ROOT / "Dockerfile"
BIN = Path(sys.executable).parent


def _instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1]) for line in lines]


def test_the_image_is_slim_non_root_and_installs_dependencies_before_the_code():
    steps = _instructions()
    kinds = [kind for kind, _ in steps]
    assert steps[0][0] == "FROM" and re.fullmatch(r"python:3\.11\.\d+-slim-\w+", steps[0][1])  # a pinned release
    deps = next(i for i, (kind, args) in enumerate(steps) if kind == "RUN" and "requirements" in args)
    code = next(i for i, (kind, args) in enumerate(steps) if kind == "COPY" and args.startswith("reglib "))
    assert deps < code
    user = max(i for i, kind in enumerate(kinds) if kind == "USER")
    assert steps[user][1] not in ("root", "0") and user < kinds.index("CMD")
    assert "/livez" in dict(steps)["HEALTHCHECK"]
    assert dict(steps)["CMD"] == '["reglib", "serve", "--host", "0.0.0.0"]'
    ignored = (ROOT / ".dockerignore").read_text().split()
    copied = [word for kind, args in steps if kind == "COPY" for word in args.split()[:-1]]
    assert copied and not set(copied) & set(ignored)


def test_the_dependency_step_lists_the_service_and_dask_requirements(tmp_path):
    run = next(args for kind, args in _instructions() if kind == "RUN" and "requirements" in args)
    python_call = shlex.split(run.split(">", 1)[0])
    assert python_call[:2] == ["python", "-c"]
    done = subprocess.run([sys.executable, "-c", python_call[2]], cwd=ROOT, capture_output=True, text=True,
                          timeout=60, check=True)
    names = {Requirement(line).name for line in done.stdout.split()}
    assert {"numpy", "opencv-contrib-python-headless", "fastapi", "uvicorn", "dask"} <= names


@pytest.mark.parametrize("command", [["reglib", "serve", "--help"], ["reglib", "batch", "--help"],
                                     ["dask", "scheduler", "--help"], ["dask", "worker", "--help"]])
def test_the_commands_the_image_documents_exist(command):
    done = subprocess.run([str(BIN / command[0]), *command[1:]], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "usage" in done.stdout.lower()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.mark.slow
def test_the_health_check_fails_without_the_service_and_passes_once_it_runs(tmp_path):
    check = shlex.split(dict(_instructions())["HEALTHCHECK"].split("CMD", 1)[1])
    port = _free_port()
    check = [sys.executable if word == "python" else word.replace(":8000/", f":{port}/") for word in check]
    assert subprocess.run(check, capture_output=True, timeout=30).returncode != 0
    log = tmp_path / "serve.log"
    with log.open("wb") as out:
        server = subprocess.Popen([str(BIN / "reglib"), "serve", "--host", "127.0.0.1", "--port", str(port),
                                   "--workers", "1"], stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 90
        while subprocess.run(check, capture_output=True, timeout=30).returncode != 0:
            assert server.poll() is None, log.read_text()
            assert time.monotonic() < deadline, log.read_text()
            time.sleep(0.5)
    finally:
        server.terminate()
        server.wait(timeout=30)
