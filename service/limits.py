"""The request guard: media type and byte limits, enforced before and while the body streams in.

A body over its limit is refused from ``Content-Length`` before a byte of it is read, and, when
the length is not announced (chunked uploads), as soon as the running count passes the limit: the
guard raises a :class:`~service.problems.Problem` out of ``receive`` and the rest is never read.
"""
from __future__ import annotations

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .problems import INVALID_BODY, TOO_LARGE, UNSUPPORTED_FORMAT, Problem, problem_body

__all__ = ["RequestGuard", "JSON_PATHS", "MULTIPART_PATHS"]

JSON_PATHS = frozenset({"/v1/filter", "/v1/register"})
MULTIPART_PATHS = frozenset({"/v1/match", "/v1/warp", "/v1/flow"})


class RequestGuard:
    def __init__(self, app: ASGIApp, *, max_json_bytes: int, max_upload_bytes: int) -> None:
        self.app = app
        self.max_json_bytes = max_json_bytes
        self.max_upload_bytes = max_upload_bytes

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
                await _refuse(send, 413, TOO_LARGE, f"the body is {int(length)} bytes, over the limit of {limit}")
                return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise Problem(413, TOO_LARGE, f"the body is over the limit of {limit} bytes")
            return message

        await self.app(scope, limited_receive, send)


async def _refuse(send: Send, status: int, type_: str, detail: str) -> None:
    body = problem_body(status, type_, detail)
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/problem+json"),
                            (b"content-length", str(len(body)).encode()), (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})
