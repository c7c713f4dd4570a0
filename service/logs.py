"""Log lines of the service: text for a terminal, or one JSON object a line (``REGLIB_LOG_FORMAT=json``).

Every line a request causes names its request id (the ``request_id`` attribute a record carries,
else the id of the request being handled, from :data:`service.pool.job_context`). The access line
of each request (logger ``service.access``) also carries ``method``, ``path``, ``status`` and
``duration_ms``; a JSON line looks like::

    {"time": "2026-12-01T09:30:00.123Z", "level": "info", "logger": "service.access",
     "message": "POST /v1/match 200 412.3 ms", "request_id": "9f0c...", "method": "POST",
     "path": "/v1/match", "status": 200, "duration_ms": 412.3, "client": "127.0.0.1"}

With API keys, the access line also names the caller by its key's id (``"caller": "1a2b3c4d5e6f"``,
12 hex digits of the key's SHA-256; :mod:`service.auth`), never by the key.

:func:`log_config` is the :func:`logging.config.dictConfig` dictionary ``reglib serve`` hands to
uvicorn, so uvicorn's own lines (startup, errors) come out in the same format; uvicorn's access
log is replaced by ours (it knows no request id).
"""
from __future__ import annotations

import json
import logging
import time
from typing import Any, Literal

from .pool import job_context

__all__ = ["JsonFormatter", "TextFormatter", "log_config", "request_id_of"]

#: Record attributes copied into a JSON line when present.
FIELDS = ("method", "path", "status", "duration_ms", "client", "caller", "worker", "pid")


def request_id_of(record: logging.LogRecord) -> str | None:
    """The request id a record is about: its own ``request_id`` attribute, else the current request's."""
    rid = getattr(record, "request_id", None)
    return rid if rid else job_context.get().get("request_id")


class JsonFormatter(logging.Formatter):
    """One JSON object a line: time (UTC, ms), level, logger, message, request_id, access fields, exc."""

    def format(self, record: logging.LogRecord) -> str:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        line: dict[str, Any] = {"time": f"{stamp}.{int(record.msecs):03d}Z", "level": record.levelname.lower(),
                                "logger": record.name, "message": record.getMessage()}
        rid = request_id_of(record)
        if rid:
            line["request_id"] = rid
        for key in FIELDS:
            if key in record.__dict__:
                line[key] = record.__dict__[key]
        if record.exc_info:
            line["exc"] = self.formatException(record.exc_info)
        elif record.exc_text:
            line["exc"] = record.exc_text
        return json.dumps(line, default=str, ensure_ascii=False)


class TextFormatter(logging.Formatter):
    """``time level logger: message [request_id]`` (and the traceback, if any)."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s")

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        rid = request_id_of(record)
        if not rid:
            return text
        first, sep, rest = text.partition("\n")
        return f"{first} [{rid}]{sep}{rest}"


def log_config(fmt: Literal["text", "json"], level: str = "info") -> dict[str, Any]:
    """The ``dictConfig`` of the server process: one stderr handler for uvicorn's loggers and ours."""
    formatter = "service.logs.JsonFormatter" if fmt == "json" else "service.logs.TextFormatter"
    level = level.upper()
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"default": {"()": formatter}},
        "handlers": {"stderr": {"class": "logging.StreamHandler", "formatter": "default",
                                "stream": "ext://sys.stderr"}},
        "loggers": {
            "uvicorn": {"handlers": ["stderr"], "level": level, "propagate": False},
            "uvicorn.error": {"handlers": ["stderr"], "level": level, "propagate": False},
            "uvicorn.access": {"handlers": [], "level": "WARNING", "propagate": False},
            "service": {"handlers": ["stderr"], "level": level, "propagate": False},
        },
        "root": {"handlers": ["stderr"], "level": "WARNING"},
    }
