"""Settings errors: one line naming the REGLIB_* variable and what it accepts, never pydantic's report."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from reglib.errors import InputError
from service.config import Settings, SettingsError, describe_setting

BAD_VARIABLES = [
    ("REGLIB_WORKERS", "abc", "REGLIB_WORKERS must be an integer from 1 to 256, got 'abc'"),
    ("REGLIB_QUEUE_SIZE", "-3", "REGLIB_QUEUE_SIZE must be an integer from 0 to 10000, got '-3'"),
    ("REGLIB_MAX_UPLOAD_BYTES", "32MB",
     "REGLIB_MAX_UPLOAD_BYTES must be a whole number of bytes >= 1024 (no unit: 32 MiB is 33554432), got '32MB'"),
    ("REGLIB_LOG_FORMAT", "yaml", "REGLIB_LOG_FORMAT must be one of text, json, got 'yaml'"),
    ("REGLIB_COMPUTE_TIMEOUT_S", "0", "REGLIB_COMPUTE_TIMEOUT_S must be a number of seconds > 0 and <= 3600, got '0'"),
    ("REGLIB_ALLOWED_FORMATS", "png,gif",
     "REGLIB_ALLOWED_FORMATS must be a comma-separated subset of png,jpeg,tiff,bmp,webp,nifti,metaimage,nrrd, "
     "got 'png,gif'"),
    ("REGLIB_FAULT_INJECTION", "maybe", "REGLIB_FAULT_INJECTION must be true or false, got 'maybe'"),
]


def _environ(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.upper().startswith("REGLIB_")}
    return {**env, **extra}


@pytest.mark.parametrize(("name", "value", "message"), BAD_VARIABLES, ids=[c[0] for c in BAD_VARIABLES])
def test_a_bad_variable_is_one_sentence_naming_it(monkeypatch, name, value, message):
    monkeypatch.setenv(name, value)
    with pytest.raises(SettingsError) as info:
        Settings()
    # one problem: not the default worker memory that could not be computed after another field's error
    assert info.value.problems == (message,) and str(info.value) == message
    assert isinstance(info.value, InputError)


def test_keywords_are_named_as_keywords_and_every_problem_is_listed(monkeypatch):
    monkeypatch.setenv("REGLIB_WORKERS", "abc")
    with pytest.raises(SettingsError) as info:
        Settings(queue_size=-1, max_pixels=0)
    assert info.value.problems == ("REGLIB_WORKERS must be an integer from 1 to 256, got 'abc'",
                                   "`queue_size` must be an integer from 0 to 10000, got -1",
                                   "`max_pixels` must be an integer >= 1, got 0")
    with pytest.raises(SettingsError, match=r"`wrokers` is not a setting; the settings are \['allowed_formats'"):
        Settings(wrokers=2)
    assert Settings(workers=3).workers == 3  # a keyword overrides the variable


def test_describe_setting_reads_the_declared_bounds():
    assert describe_setting("workers") == "an integer from 1 to 256"
    assert describe_setting("max_json_bytes").startswith("a whole number of bytes >= 1024")
    assert describe_setting("shutdown_grace_s") == "a number of seconds from 0 to 3600"


@pytest.mark.parametrize(("name", "value", "message"), BAD_VARIABLES[:4], ids=[c[0] for c in BAD_VARIABLES[:4]])
def test_reglib_serve_with_a_bad_variable_exits_2_with_one_line(name, value, message):
    done = subprocess.run([sys.executable, "-m", "reglib.cli", "serve", "--port", "0"], capture_output=True,
                          text=True, timeout=120, env=_environ(**{name: value}))
    assert done.returncode == 2, done.stderr
    assert done.stderr == f"reglib serve: error: {message}\n"
    assert "Traceback" not in done.stderr and done.stdout == ""


def test_reglib_serve_names_the_workers_flag():
    done = subprocess.run([sys.executable, "-m", "reglib.cli", "serve", "--port", "0", "--workers", "0"],
                          capture_output=True, text=True, timeout=120, env=_environ(REGLIB_WORKERS="abc"))
    assert done.returncode == 2
    assert done.stderr == "reglib serve: error: `--workers` must be an integer from 1 to 256, got 0\n"


def test_uvicorn_on_the_factory_names_the_variable():
    done = subprocess.run([sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--port", "0"],
                          capture_output=True, text=True, timeout=120, env=_environ(REGLIB_WORKERS="abc"))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "REGLIB_WORKERS must be an integer from 1 to 256, got 'abc'" in done.stderr
