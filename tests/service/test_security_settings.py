"""The settings of a service beyond localhost (keys file, CORS origins, /metrics access, per-key limit), one line per
bad value like every setting; the keys file's format; key ids; and the listening addresses the warning reads."""
from __future__ import annotations

import hashlib
import socket

import pytest

from service.auth import ApiKeys, is_loopback, key_id
from service.config import Settings, SettingsError, read_keys
from service.exposure import listening_addresses
from service.headers import inline_script_policy


def test_a_keys_file_that_cannot_be_used_is_one_line_naming_the_variable(monkeypatch, tmp_path):
    missing = tmp_path / "missing.txt"
    monkeypatch.setenv("REGLIB_API_KEYS_FILE", str(missing))
    with pytest.raises(SettingsError) as info:
        Settings(workers=1)
    assert info.value.problems == (f"REGLIB_API_KEYS_FILE must be a readable file of API keys, one a line, got "
                                   f"'{missing}' (cannot be read: No such file or directory)",)
    empty = tmp_path / "empty.txt"
    empty.write_text("# only a comment\n\n")
    with pytest.raises(SettingsError, match=r"^`api_keys_file` must be a readable file .* \(holds no key\)$"):
        Settings(workers=1, api_keys_file=str(empty))
    spaced = tmp_path / "spaced.txt"
    spaced.write_text("good-key\nsecret with spaces\n")
    with pytest.raises(SettingsError, match=r"\(line 2 is not one key \(printable ASCII, no spaces\)\)$") as info:
        Settings(workers=1, api_keys_file=str(spaced))
    assert "secret" not in str(info.value).split("got")[1].split("(")[1]  # the reason never repeats a key


def test_cors_origins_metrics_access_and_the_per_key_limit_are_checked(monkeypatch):
    monkeypatch.setenv("REGLIB_CORS_ORIGINS", "https://ok.example, http://allowed.example/app")
    with pytest.raises(SettingsError) as info:
        Settings(workers=1)
    assert info.value.problems == ("REGLIB_CORS_ORIGINS must be comma-separated origins such as "
                                   "https://app.example.org (scheme://host[:port], no path), or *, got "
                                   "'https://ok.example, http://allowed.example/app'",)
    monkeypatch.setenv("REGLIB_CORS_ORIGINS", "HTTPS://Ok.Example:8443,http://127.0.0.1:3000, *")
    assert Settings(workers=1).cors_origins == ("https://ok.example:8443", "http://127.0.0.1:3000", "*")
    monkeypatch.delenv("REGLIB_CORS_ORIGINS")
    assert Settings(workers=1).cors_origins == ()  # off by default
    monkeypatch.setenv("REGLIB_METRICS_ACCESS", "public")
    monkeypatch.setenv("REGLIB_MAX_IN_FLIGHT_PER_KEY", "0")
    with pytest.raises(SettingsError) as info:
        Settings(workers=1)
    assert info.value.problems == ("REGLIB_MAX_IN_FLIGHT_PER_KEY must be an integer from 1 to 100000, got '0'",
                                   "REGLIB_METRICS_ACCESS must be one of auto, open, keys, got 'public'")


def test_the_per_key_limit_defaults_to_half_the_pool():
    assert Settings(workers=4, queue_size=16).max_in_flight_per_key == 10
    assert Settings(workers=1, queue_size=0).max_in_flight_per_key == 1
    assert Settings(workers=1, max_in_flight_per_key=3).max_in_flight_per_key == 3


def test_keys_files_and_key_ids(tmp_path):
    path = tmp_path / "keys"
    path.write_text("# callers\n  alpha-key-1  \n\n#beta-key-2\nalpha-key-1\ngamma~key!3\n")
    assert read_keys(path) == ("alpha-key-1", "gamma~key!3")  # comments, blanks and repeats left out
    keys = ApiKeys(str(path))
    assert len(keys) == 2
    assert keys.identify("alpha-key-1") == key_id("alpha-key-1") == hashlib.sha256(b"alpha-key-1").hexdigest()[:12]
    assert keys.identify("gamma~key!3") is not None
    assert keys.identify("beta-key-2") is None and keys.identify("alpha-key-") is None and keys.identify("") is None
    path.write_text("beta-key-2\n")
    assert keys.reload() is True and keys.identify("beta-key-2") and keys.identify("alpha-key-1") is None
    path.write_text("")
    assert keys.reload() is False and keys.identify("beta-key-2")  # an unusable file keeps the old keys


def test_loopback_addresses():
    assert is_loopback("127.0.0.1") and is_loopback("127.8.9.10") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("10.1.2.3") and not is_loopback("testserver")
    assert not is_loopback(None)


def test_listening_addresses_are_this_processs_listening_sockets():
    before = listening_addresses()
    with socket.socket() as s4, socket.socket(socket.AF_INET6) as s6:
        s4.bind(("127.0.0.1", 0))
        s6.bind(("::1", 0))
        assert listening_addresses() == before  # bound, not listening
        s4.listen()
        s6.listen()
        assert sorted(listening_addresses()) == sorted([*before, "127.0.0.1", "::1"])
    assert listening_addresses() == before


def test_inline_scripts_are_allowed_by_their_hash_only():
    html = "<p>x</p><script src='/a.js'></script><script>go(1)</script>"
    digest = "oopyQloGglvWmMz5jW49OLcPG4Zf/xbfwxZIQgBfJ+w="  # base64 of sha256(b"go(1)"), as CSP hashes it
    assert inline_script_policy(html, "default-src 'self'; script-src 'self'; frame-ancestors 'none'") == (
        f"default-src 'self'; script-src 'self' 'sha256-{digest}'; frame-ancestors 'none'")


def test_metrics_need_a_key_by_the_setting_and_the_address_a_request_arrived_on():
    from service.auth import metrics_need_key

    def scope(host):
        return {"type": "http", "path": "/metrics", "server": (host, 8000) if host else None}

    auto, open_, keys = (Settings(workers=1, metrics_access=m) for m in ("auto", "open", "keys"))
    assert [metrics_need_key(auto, scope(h)) for h in ("127.0.0.1", "::1", "10.0.0.5", "0.0.0.0", None)] == [
        False, False, True, True, True]
    assert not any(metrics_need_key(open_, scope(h)) for h in ("127.0.0.1", "10.0.0.5"))
    assert all(metrics_need_key(keys, scope(h)) for h in ("127.0.0.1", "10.0.0.5"))


def test_metrics_behind_the_keys(tmp_path):
    from fastapi.testclient import TestClient

    from service.app import create_app

    path = tmp_path / "keys.txt"
    path.write_text("metrics-key-1\n")
    for access, without in (("keys", 401), ("open", 200)):
        settings = Settings(workers=1, queue_size=0, api_keys_file=str(path), metrics_access=access)
        with TestClient(create_app(settings)) as client:
            assert client.get("/metrics").status_code == without
            r = client.get("/metrics", headers={"X-API-Key": "metrics-key-1"})
            assert r.status_code == 200 and "reglib_http_requests_total" in r.text
            assert client.get("/livez").status_code == 200 and client.get("/readyz").status_code == 200
