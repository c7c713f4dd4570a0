"""The service's limits on what one request may ask: bytes, points, and the match form's bounds.

Bytes and media types (:class:`RequestGuard`, an ASGI middleware): a body over its limit is refused
from ``Content-Length`` before a byte of it is read, and, when the length is not announced (chunked
uploads), as soon as the running count passes the limit: the guard raises a
:class:`~service.problems.Problem` out of ``receive`` and the rest is never read. A JSON body is parsed
on the event loop, which answers every other request meanwhile, so the guard also counts its ``[`` as
it arrives: more arrays than the endpoint's point sets may hold under ``max_points`` is a 413 before
any parsing (a body of many tiny points takes far longer to parse than its bytes suggest).

Points (:func:`check_points`): each set of a JSON request holds at most ``max_points`` points, an
organized scan counting its H * W pixels.

The match form (:func:`form_specs`, :func:`check_form_bounds`): the library's declarations of a
match request's fields, with the settings' tighter bounds on ``max_pixels`` and ``max_keypoints``.
"""
from __future__ import annotations

import dataclasses
from typing import Any

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from reglib import MatchRequest
from reglib.errors import InputError
from reglib.matching import match_request_specs
from reglib.options import OptionSpec

from .config import Settings
from .problems import INVALID_BODY, INVALID_INPUT, TOO_LARGE, UNSUPPORTED_FORMAT, Problem, problem_body
from .schemas import is_scan_row
from .units import human_bytes, size_over_limit

__all__ = ["RequestGuard", "JSON_PATHS", "MULTIPART_PATHS", "count_points", "check_points", "form_specs",
           "check_form_bounds"]

JSON_PATHS = frozenset({"/v1/filter", "/v1/register"})
#: The point sets of each JSON endpoint's body (register: model, target, their colours and normals).
_POINT_SETS = {"/v1/filter": 2, "/v1/register": 6}
#: A body refused part-way is not read on: the connection closes after the answer.
_CLOSE = {"Connection": "close"}
#: ``[`` of a JSON body beside its points' own (the sets' brackets, options).
_SPARE_ARRAYS = 4096
MULTIPART_PATHS = frozenset({"/v1/match", "/v1/match/bundle", "/v1/warp", "/v1/flow", "/v1/confidence"})


class RequestGuard:
    """Refuse a POST to a compute endpoint whose media type is wrong (415) or whose body is over its limit
    (413): ``max_json_bytes`` for the JSON endpoints, ``max_upload_bytes`` for the multipart ones."""

    def __init__(self, app: ASGIApp, *, max_json_bytes: int, max_upload_bytes: int, max_points: int = 20_000) -> None:
        self.app = app
        self.max_json_bytes = max_json_bytes
        self.max_upload_bytes = max_upload_bytes
        self.max_points = max_points

    def max_arrays(self, path: str) -> int:
        """The most ``[`` a valid body of the JSON endpoint ``path`` holds: a point is one array, a row of an
        organized scan one more (at most one a point), for each of its point sets."""
        return _POINT_SETS.get(path, 0) * (2 * self.max_points + 1) + _SPARE_ARRAYS

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "") if scope["type"] == "http" else ""
        if scope["type"] != "http" or scope.get("method") != "POST" or path not in JSON_PATHS | MULTIPART_PATHS:
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        ctype = headers.get("content-type", "").split(";")[0].strip().lower()
        if path in JSON_PATHS:
            limit, wanted, ok = self.max_json_bytes, "application/json", ctype == "application/json" or (
                ctype.startswith("application/") and ctype.endswith("+json"))
        else:
            limit, wanted, ok = self.max_upload_bytes, "multipart/form-data", ctype == "multipart/form-data"
        if not ok:
            await _refuse(send, 415, UNSUPPORTED_FORMAT, f"{path} takes {wanted}, got {ctype or 'no Content-Type'}")
            return
        length = headers.get("content-length")
        if length is not None:
            if not length.isdigit():
                await _refuse(send, 400, INVALID_BODY, "Content-Length is not a number")
                return
            if int(length) > limit:
                await _refuse(send, 413, TOO_LARGE, f"the body is {size_over_limit(int(length), limit)}")
                return
        received, arrays = 0, 0
        max_arrays = self.max_arrays(path) if path in JSON_PATHS else None

        async def limited_receive() -> Message:
            nonlocal received, arrays
            message = await receive()
            if message["type"] == "http.request":
                chunk = message.get("body", b"")
                received += len(chunk)
                if received > limit:
                    raise Problem(413, TOO_LARGE, f"the body is over the limit of {human_bytes(limit)}",
                                  headers=_CLOSE)
                if max_arrays is not None:
                    arrays += chunk.count(b"[")
                    if arrays > max_arrays:
                        raise Problem(413, TOO_LARGE, f"the body holds more than {max_arrays} JSON arrays, more "
                                      f"than point sets of at most {self.max_points} points need", headers=_CLOSE)
            return message

        await self.app(scope, limited_receive, send)


async def _refuse(send: Send, status: int, type_: str, detail: str) -> None:
    body = problem_body(status, type_, detail)
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/problem+json"),
                            (b"content-length", str(len(body)).encode()), (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


def count_points(points: list[Any]) -> int:
    """Points in a set: rows of (N, D), or the pixels of an organized (H, W, 3) scan."""
    return sum(len(row) if is_scan_row(row) else 1 for row in points)


def check_points(settings: Settings, **sets: list[Any]) -> None:
    """A 413 naming the first set (by keyword) with more than ``settings.max_points`` points."""
    for name, points in sets.items():
        n = count_points(points)
        if n > settings.max_points:
            raise Problem(413, TOO_LARGE, f"`{name}` has {n} points, over the limit of {settings.max_points}")


def _bounds(settings: Settings) -> dict[str, int]:
    """The match request's fields whose upper bound the settings tighten, with that bound."""
    return {"max_pixels": settings.max_pixels, "max_keypoints": settings.max_keypoints_limit}


def form_specs(settings: Settings) -> tuple[OptionSpec, ...]:
    """The match request's fields as this service takes them: the library's, with the settings'
    bounds on ``max_pixels`` and ``max_keypoints`` (and ``max_pixels`` defaulting to the limit)."""
    tighter = _bounds(settings)
    out = []
    for spec in match_request_specs():
        if spec.name in tighter:
            spec = spec.bounded(tighter[spec.name])
            if spec.name == "max_pixels":
                spec = dataclasses.replace(spec, default=settings.max_pixels)
        out.append(spec)
    return tuple(out)


def check_form_bounds(request: MatchRequest, settings: Settings) -> None:
    """A 422 naming a given field of the parsed ``request`` that is beyond the service's bound.

    The library has parsed and checked the request against its own bounds; this checks the values
    that were given (``request.given``) against the tighter ones of :func:`form_specs`, with the
    library's own check and message. A field left out keeps the library's default.
    """
    specs = {spec.name: spec for spec in form_specs(settings)}
    for name in _bounds(settings):
        if name in request.given:
            try:
                specs[name].check(request.given[name])
            except InputError as exc:
                raise Problem(422, INVALID_INPUT, str(exc)) from None
