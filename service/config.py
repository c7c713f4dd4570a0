"""Service settings, read once per app from ``REGLIB_*`` environment variables (pydantic-settings).

Every limit has a safe default; the README lists them all, and each field's description says what it
bounds. ``create_app(settings)`` takes an explicit :class:`Settings` (tests do), else builds one from
the environment. A value that cannot be used is a :class:`SettingsError`: one line per bad value,
naming the ``REGLIB_*`` variable (or the keyword argument) and what it accepts, never pydantic's
report. The default worker memory cap is a share of the memory this process may use
(:func:`usable_memory`: 75 % of the smaller of MemTotal and the cgroup limit) divided by the workers.
"""
from __future__ import annotations

import os
import re
from collections.abc import Iterable
from typing import Annotated, Any, Literal, get_args, get_origin

from annotated_types import Ge, Gt, Le, Lt
from pydantic import Field, ValidationError, field_validator
from pydantic.fields import FieldInfo
from pydantic_core import PydanticCustomError
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from reglib.errors import InputError

__all__ = ["Settings", "SettingsError", "ALL_FORMATS", "ENV_PREFIX", "describe_setting", "usable_memory", "read_keys"]

ALL_FORMATS = ("png", "jpeg", "tiff", "bmp", "webp", "nifti", "metaimage", "nrrd")  # reglib.io.ALLOWED_FORMATS
ENV_PREFIX = "REGLIB_"


class SettingsError(InputError):
    """Settings that cannot be used; the message has one clause per bad value, e.g.
    ``REGLIB_WORKERS must be an integer from 1 to 256, got 'abc'``.

    Attributes
    ----------
    problems : tuple of str
        One sentence per bad value, each naming its ``REGLIB_*`` variable (or keyword argument).
    """

    def __init__(self, problems: Iterable[str]) -> None:
        self.problems = tuple(problems)
        super().__init__("; ".join(self.problems))


def _default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def usable_memory() -> int:
    """Bytes of memory this process may use: MemTotal, or the cgroup (v2 or v1) limit when lower."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path, encoding="ascii") as f:
                text = f.read().strip()
        except OSError:
            continue
        if text.isdigit() and 0 < int(text) < total:
            total = int(text)
    return int(total)


def read_keys(path: str | os.PathLike[str]) -> tuple[str, ...]:
    """The API keys of a keys file: one a line, blank lines and lines starting with ``#`` ignored.

    Raises
    ------
    ValueError
        The file cannot be read, holds no key, or a line holds something that cannot be a header value
        (spaces or characters beyond printable ASCII); the message names the line, never a key.
    """
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else type(exc).__name__
        raise ValueError(f"cannot be read: {reason}") from None
    keys = []
    for number, line in enumerate(lines, start=1):
        key = line.strip()
        if not key or key.startswith("#"):
            continue
        if not all("!" <= ch <= "~" for ch in key):
            raise ValueError(f"line {number} is not one key (printable ASCII, no spaces)")
        keys.append(key)
    if not keys:
        raise ValueError("holds no key")
    return tuple(dict.fromkeys(keys))


_ORIGIN = re.compile(r"https?://(\[[0-9a-f:.]+\]|[a-z0-9]([a-z0-9.-]*[a-z0-9])?)(:[0-9]{1,5})?")


def _default_in_flight_per_key(data: dict[str, Any]) -> int:
    workers: int = data.get("workers") or _default_workers()  # (``data``: the fields validated so far)
    queue_size: int = data.get("queue_size", 16)
    return max(1, (workers + queue_size) // 2)


#: Bytes of JSON one point of ``max_points`` may need: six sets of it in one request (``/v1/register``'s model,
#: target and their colours and normals), each row three floats at full precision (24 characters at most)
#: with separators. Parsing happens on the event loop, so the body is held to what the point limit needs.
JSON_BYTES_PER_POINT = 6 * (3 * 26 + 4)
#: Bytes of a JSON request beside its points (method, options, seed).
JSON_SLACK_BYTES = 256 << 10


def _default_json_bytes(data: dict[str, Any]) -> int:
    return int(data.get("max_points", 20_000)) * JSON_BYTES_PER_POINT + JSON_SLACK_BYTES


def _default_connections() -> int:
    """Half the files this process may open (RLIMIT_NOFILE), less room for its own (pipes to workers, logs), from
    16 to 1024: a connection takes one file, and running out of files stops the server accepting any."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    except (ImportError, OSError, ValueError):
        return 1024
    if soft == getattr(resource, "RLIM_INFINITY", -1) or soft <= 0:
        return 1024
    return max(16, min(1024, (soft - 64) // 2))


def _default_worker_memory(data: dict[str, Any]) -> int:
    workers = data.get("workers") or _default_workers()
    return max(256 << 20, int(0.75 * usable_memory()) // workers)


class Settings(BaseSettings):
    """Limits and sizes of one service instance (environment variables ``REGLIB_<NAME>``)."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, extra="forbid", frozen=True)

    def __init__(self, **values: Any) -> None:
        """Read the ``REGLIB_*`` variables, overridden by ``values``; a bad one is a :class:`SettingsError`."""
        try:
            super().__init__(**values)
        except ValidationError as exc:
            raise SettingsError(_problems(type(self), exc, given=set(values))) from None

    workers: int = Field(default_factory=_default_workers, ge=1, le=256,
                         description="processes in the compute pool (default: the CPUs this process may use)")
    queue_size: int = Field(default=16, ge=0, le=10_000,
                            description="requests that may wait for a free worker; beyond it: 429")
    compute_timeout_s: float = Field(default=60.0, gt=0, le=3600,
                                     description="wall time one request may wait and compute; beyond it: 504")
    retry_after_s: int = Field(default=1, ge=1, le=3600, description="Retry-After sent with 429 and 503")
    max_upload_bytes: int = Field(default=32 * 1024 * 1024, ge=1024,
                                  description="bytes of one multipart request (both images and fields)")
    max_pixels: int = Field(default=25_000_000, ge=1, description="pixels of one image, read from its header")
    max_points: int = Field(default=20_000, ge=1, description="points per set in one JSON request")
    max_json_bytes: int = Field(
        default_factory=_default_json_bytes, ge=1024,
        description="bytes of one JSON request body (default: what max_points needs, "
                    f"{JSON_BYTES_PER_POINT} bytes a point plus {JSON_SLACK_BYTES >> 10} KiB)")
    opencv_max_pixels: int = Field(default=2**28, ge=1,
                                   description="OPENCV_IO_MAX_IMAGE_PIXELS of the workers (OpenCV's own guard)")
    allowed_formats: Annotated[tuple[str, ...], NoDecode] = Field(
        default=ALL_FORMATS, description="comma-separated subset of png,jpeg,tiff,bmp,webp,nifti,metaimage,nrrd")
    max_keypoints_limit: int = Field(default=20_000, ge=1, description="largest max_keypoints a request may ask")
    max_form_parts: int = Field(default=32, ge=3, description="parts (files + fields) of one multipart request")
    worker_max_memory: int = Field(
        default_factory=_default_worker_memory, ge=0,
        description="bytes of address space one job may add to an idle worker (RLIMIT_AS); beyond it the job gets "
                    "413 and its worker is replaced; 0: no cap (default: 75 % of the machine's or cgroup's memory "
                    "divided by the workers)")
    header_timeout_s: float = Field(
        default=10.0, gt=0, le=3600,
        description="seconds a connection may take to send a request's line and headers, from its opening or the "
                    "previous answer; beyond it: 408 and the connection closed")
    body_timeout_s: float = Field(
        default=30.0, gt=0, le=3600,
        description="seconds a request's body may pause between two pieces; beyond it: 408 and the connection closed")
    max_connections: int = Field(
        default_factory=_default_connections, ge=1, le=1_000_000,
        description="open HTTP connections; at the limit a new one closes the one that has waited longest for a "
                    "request, or is served /livez and /readyz only (default: half the open files this process may "
                    "have, less room for the rest, from 16 to 1024)")
    shutdown_grace_s: float = Field(
        default=30.0, ge=0, le=3600,
        description="on SIGTERM: seconds the requests in flight may take to finish while new ones get 503; "
                    "then the server stops and exits 0")
    log_format: Literal["text", "json"] = Field(
        default="text", description="log lines as text, or one JSON object a line (with the request id)")
    api_keys_file: str | None = Field(
        default=None,
        description="a file of API keys, one a line (blank lines and # comments ignored), read at start-up and on "
                    "SIGHUP; when set, every /v1/* request needs `Authorization: Bearer <key>` or `X-API-Key: <key>`")
    max_in_flight_per_key: int = Field(
        default_factory=_default_in_flight_per_key, ge=1, le=100_000,
        description="requests one API key may have in flight; beyond it: 429 (default: half of workers + "
                    "queue_size, at least 1)")
    metrics_access: Literal["auto", "open", "keys"] = Field(
        default="auto",
        description="/metrics without a key (open), only with one (keys), or auto: open to requests that arrive on "
                    "a loopback address (all of them on a 127.0.0.1 bind), behind the keys otherwise")
    cors_origins: Annotated[tuple[str, ...], NoDecode] = Field(
        default=(), description="comma-separated origins (https://host[:port]) whose pages may call the API, or *; "
                                "empty: cross-origin calls are refused")
    fault_injection: bool = Field(
        default=False,
        description="TEST HOOK, never in production: when true, a request with the header `X-Reglib-Fault: crash` "
                    "has its job kill its worker (SIGKILL) instead of computing, on every attempt (fault tests, soak)")

    @field_validator("allowed_formats", mode="before")
    @classmethod
    def _split_formats(cls, value: object) -> object:
        if isinstance(value, str):
            value = [v.strip().lower() for v in value.split(",") if v.strip()]
        if isinstance(value, (list, tuple)):
            value = tuple("jpeg" if v == "jpg" else v for v in value)
            bad = sorted(set(value) - set(ALL_FORMATS))
            if bad or not value:
                raise ValueError(f"allowed_formats must be a non-empty subset of {list(ALL_FORMATS)}, "
                                 f"got {bad or value}")
        return value


    @field_validator("api_keys_file", mode="after")
    @classmethod
    def _check_keys_file(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                read_keys(value)
            except ValueError as exc:
                raise PydanticCustomError("setting_reason", "{reason}", {"reason": str(exc)}) from None
        return value

    @field_validator("cors_origins", mode="before")
    @classmethod
    def _split_origins(cls, value: object) -> object:
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if isinstance(value, (list, tuple)):
            value = tuple(str(v).lower() for v in value)
            bad = [v for v in value if v != "*" and not _ORIGIN.fullmatch(v)]
            if bad:
                raise ValueError(f"not origins: {bad}")
        return value


def _bounds(info: FieldInfo) -> str:
    """The numeric bounds of a field in words: ``from 1 to 256``, ``> 0 and <= 3600``, ``>= 1024``."""
    low = next((f">= {m.ge}" for m in info.metadata if isinstance(m, Ge)), None)
    low = next((f"> {m.gt}" for m in info.metadata if isinstance(m, Gt)), low)
    high = next((f"<= {m.le}" for m in info.metadata if isinstance(m, Le)), None)
    high = next((f"< {m.lt}" for m in info.metadata if isinstance(m, Lt)), high)
    if low and high and low.startswith(">=") and high.startswith("<="):
        return f"from {low[3:]} to {high[3:]}"
    return " and ".join(part for part in (low, high) if part)


def describe_setting(name: str) -> str:
    """What the setting ``name`` accepts, in words (for error messages and help texts)."""
    info = Settings.model_fields[name]
    if name == "allowed_formats":
        return f"a comma-separated subset of {','.join(ALL_FORMATS)}"
    if name == "api_keys_file":
        return "a readable file of API keys, one a line"
    if name == "cors_origins":
        return "comma-separated origins such as https://app.example.org (scheme://host[:port], no path), or *"
    annotation = info.annotation
    if get_origin(annotation) is Literal:
        return "one of " + ", ".join(str(choice) for choice in get_args(annotation))
    if annotation is bool:
        return "true or false"
    bounds = _bounds(info)
    if name.endswith(("_bytes", "_memory")):
        return f"a whole number of bytes {bounds} (no unit: 32 MiB is {32 << 20})"
    kind = "an integer" if annotation is int else "a number"
    if name.endswith("_s"):
        kind += " of seconds"
    return f"{kind} {bounds}".rstrip()


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _problems(cls: type[Settings], exc: ValidationError, *, given: set[str]) -> list[str]:
    """One sentence per real error of ``exc``, naming the variable (or the keyword when it was given)."""
    problems = []
    for error in exc.errors(include_url=False):
        if error["type"] == "default_factory_not_called":  # a consequence of another field's error
            continue
        name = str(error["loc"][0]) if error["loc"] else ""
        if name not in cls.model_fields:
            problems.append(f"`{name}` is not a setting; the settings are {sorted(cls.model_fields)}")
            continue
        where = f"`{name}`" if name in given else ENV_PREFIX + name.upper()
        reason = f" ({error['ctx']['reason']})" if error["type"] == "setting_reason" else ""
        shown = repr(error.get("input")) if name == "api_keys_file" else _shown(error.get("input"))  # a whole path
        problems.append(f"{where} must be {describe_setting(name)}, got {shown}{reason}")
    return problems or [str(exc)]
