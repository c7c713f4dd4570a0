"""A corpus of bad requests: each is answered 4xx application/problem+json with the right ``type``.

None of them may reach a 5xx, and no body may carry a traceback or a server path.
"""
from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

from service import problems as P

OK_POINTS = [[float(i), float(2 * i)] for i in range(10)]


def multipart(parts: list[tuple[bytes, bytes | None, bytes]], boundary: bytes = b"xBOUNDARYx") -> tuple[bytes, str]:
    """Raw multipart body from (field name, filename or None, content) parts."""
    out = []
    for name, filename, content in parts:
        disp = b'Content-Disposition: form-data; name="' + name + b'"'
        if filename is not None:
            disp += b'; filename="' + filename + b'"\r\nContent-Type: application/octet-stream'
        out.append(b"--" + boundary + b"\r\n" + disp + b"\r\n\r\n" + content + b"\r\n")
    return b"".join(out) + b"--" + boundary + b"--\r\n", "multipart/form-data; boundary=" + boundary.decode()


def png_header(width: int, height: int) -> bytes:
    """A PNG whose IHDR claims width x height, with a tiny IDAT (a decompression bomb's header)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def bmp_header(width: int, height: int) -> bytes:
    return b"BM" + struct.pack("<IHHI", 54, 0, 0, 54) + struct.pack("<IiiHHIIiiII", 40, width, height, 1, 24, 0, 0,
                                                                     0, 0, 0, 0)


def tiny_png() -> bytes:
    import cv2
    ok, buf = cv2.imencode(".png", np.zeros((8, 8), np.uint8))
    return buf.tobytes()


def tiny_jpeg() -> bytes:
    import cv2
    img = (np.indices((64, 64)).sum(0) % 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", img)
    return buf.tobytes()


def images(a: bytes, b: bytes | None = None, *fields: tuple[bytes, bytes]) -> tuple[bytes, str]:
    parts: list[tuple[bytes, bytes | None, bytes]] = [(b"image_a", b"a.png", a)]
    if b is not None:
        parts.append((b"image_b", b"b.png", b))
    parts += [(name, None, value) for name, value in fields]
    return multipart(parts)


Case = tuple[str, str, Callable[[], dict[str, Any]], int, str]


def json_raw(text: str | bytes, ctype: str = "application/json") -> Callable[[], dict[str, Any]]:
    return lambda: {"content": text.encode() if isinstance(text, str) else text, "headers": {"content-type": ctype}}


def json_body(body: Any) -> Callable[[], dict[str, Any]]:
    return lambda: {"json": body}


def mp(build: Callable[[], tuple[bytes, str]]) -> Callable[[], dict[str, Any]]:
    def make() -> dict[str, Any]:
        body, ctype = build()
        return {"content": body, "headers": {"content-type": ctype}}
    return make


def chunked(total: int) -> Callable[[], dict[str, Any]]:
    def gen() -> Iterator[bytes]:
        yield b'{"src": ['
        sent = 0
        while sent < total:
            yield b"[1.0, 2.0]," * 1000
            sent += 11000
        yield b"[1.0, 2.0]], \"dst\": []}"
    return lambda: {"content": gen(), "headers": {"content-type": "application/json"}}


PNG = tiny_png()
JPEG = tiny_jpeg()
F = "/v1/filter"
R = "/v1/register"
M = "/v1/match"

CASES: list[Case] = [
    # JSON point endpoints
    ("nan in points", F, json_raw('{"src": [[NaN, 1]], "dst": [[0, 0]]}'), 422, P.INVALID_INPUT),
    ("infinity in points", F, json_raw('{"src": [[Infinity, 1]], "dst": [[0, 0]]}'), 422, P.INVALID_INPUT),
    ("1e999 overflows to inf", F, json_raw('{"src": [[1e999, 1]], "dst": [[0, 0]]}'), 422, P.INVALID_INPUT),
    ("mismatched shapes", F, json_body({"src": OK_POINTS, "dst": OK_POINTS[:5]}), 422, P.INVALID_INPUT),
    ("2-D src with 3-D dst", F, json_body({"src": OK_POINTS, "dst": [p + [1.0] for p in OK_POINTS]}), 422,
     P.INVALID_INPUT),
    ("4-D points", F, json_body({"src": [[1, 2, 3, 4]], "dst": [[1, 2, 3, 4]]}), 422, P.INVALID_INPUT),
    ("1-D points", F, json_body({"src": [[1]], "dst": [[1]]}), 422, P.INVALID_INPUT),
    ("ragged rows", F, json_body({"src": [[1, 2], [1, 2, 3]], "dst": [[1, 2], [1, 2, 3]]}), 422, P.INVALID_INPUT),
    ("strings as coordinates", F, json_body({"src": [["a", "b"]], "dst": [[0, 0]]}), 422, P.INVALID_INPUT),
    ("points as an object", F, json_body({"src": {"x": 1}, "dst": []}), 422, P.INVALID_INPUT),
    ("unknown top-level key", F, json_body({"src": OK_POINTS, "dst": OK_POINTS, "sedd": 1}), 422, P.INVALID_INPUT),
    ("unknown option", F, json_body({"src": OK_POINTS, "dst": OK_POINTS, "options": {"betta": 1}}), 422,
     P.INVALID_INPUT),
    ("option out of range", F, json_body({"src": OK_POINTS, "dst": OK_POINTS, "options": {"beta": -1}}), 422,
     P.INVALID_INPUT),
    ("options not an object", F, json_body({"src": OK_POINTS, "dst": OK_POINTS, "options": [1]}), 422,
     P.INVALID_INPUT),
    ("unknown method", F, json_body({"src": OK_POINTS, "dst": OK_POINTS, "method": "ransac"}), 422, P.INVALID_INPUT),
    ("negative seed", F, json_body({"src": OK_POINTS, "dst": OK_POINTS, "seed": -1}), 422, P.INVALID_INPUT),
    ("seed not a number", F, json_body({"src": OK_POINTS, "dst": OK_POINTS, "seed": "abc"}), 422, P.INVALID_INPUT),
    ("missing dst", F, json_body({"src": OK_POINTS}), 422, P.INVALID_INPUT),
    ("a JSON array body", F, json_body([OK_POINTS, OK_POINTS]), 422, P.INVALID_INPUT),
    ("truncated JSON", F, json_raw('{"src": [[1, 2], [3'), 400, P.INVALID_BODY),
    ("empty JSON body", F, json_raw(""), 422, P.INVALID_INPUT),
    ("non-UTF-8 JSON body", F, json_raw(b'{"src": "\xff\xfe"}'), 400, P.INVALID_BODY),
    ("text/plain body", F, json_raw('{"src": [], "dst": []}', "text/plain"), 415, P.UNSUPPORTED_FORMAT),
    ("no content type", F, lambda: {"content": b'{"src": [], "dst": []}'}, 415, P.UNSUPPORTED_FORMAT),
    ("multipart to a JSON endpoint", F, mp(lambda: images(PNG, PNG)), 415, P.UNSUPPORTED_FORMAT),
    ("oversized JSON (Content-Length)", F, json_raw(b" " * (3 * 1024 * 1024)), 413, P.TOO_LARGE),
    ("oversized JSON (chunked, no length)", F, chunked(3 * 1024 * 1024), 413, P.TOO_LARGE),
    ("too many points", F, json_body({"src": [[0.0, 0.0]] * 5001, "dst": [[0.0, 0.0]] * 5001}), 413, P.TOO_LARGE),
    ("register: unknown method", R, json_body({"model": OK_POINTS, "target": OK_POINTS, "method": "icp"}), 422,
     P.INVALID_INPUT),
    ("register: NaN", R, json_raw('{"model": [[NaN, 0]], "target": [[0, 0]]}'), 422, P.INVALID_INPUT),
    ("register: unknown key", R, json_body({"model": OK_POINTS, "target": OK_POINTS, "opts": {}}), 422,
     P.INVALID_INPUT),
    ("register: missing target", R, json_body({"model": OK_POINTS}), 422, P.INVALID_INPUT),
    ("register: ragged colours with a null", R, json_body({"model": OK_POINTS, "target": OK_POINTS,
                                                           "method": "color-gmm", "model_colors": [[None, 1]]}),
     422, P.INVALID_INPUT),
    ("register: ragged normals with a null", R, json_body({"model": OK_POINTS, "target": OK_POINTS,
                                                           "target_normals": [[None, 1]]}), 422, P.INVALID_INPUT),
    # image endpoints
    ("zero-byte image", M, mp(lambda: images(b"", PNG)), 400, P.UNDECODABLE_IMAGE),
    ("wrong magic bytes", M, mp(lambda: images(b"this is not an image at all", PNG)), 400, P.UNDECODABLE_IMAGE),
    ("truncated JPEG", M, mp(lambda: images(JPEG[: len(JPEG) // 3], JPEG)), 400, P.UNDECODABLE_IMAGE),
    ("truncated PNG", M, mp(lambda: images(PNG, PNG[:40])), 400, P.UNDECODABLE_IMAGE),
    ("PNG header claiming 65535 x 65535", M, mp(lambda: images(png_header(65535, 65535), PNG)), 413, P.TOO_LARGE),
    ("BMP header claiming 30000 x 30000", M, mp(lambda: images(PNG, bmp_header(30000, 30000))), 413, P.TOO_LARGE),
    ("PNG header claiming 0 x 10", M, mp(lambda: images(png_header(0, 10), PNG)), 400, P.UNDECODABLE_IMAGE),
    ("GIF image", M, mp(lambda: images(b"GIF89a" + b"\x00" * 40, PNG)), 415, P.UNSUPPORTED_FORMAT),
    ("PNM image", M, mp(lambda: images(b"P5\n8 8\n255\n" + b"\x00" * 64, PNG)), 415, P.UNSUPPORTED_FORMAT),
    ("missing image_b", M, mp(lambda: images(PNG)), 422, P.INVALID_INPUT),
    ("image_a as a text field", M, mp(lambda: multipart([(b"image_a", None, b"abc"), (b"image_b", b"b", PNG)])),
     422, P.INVALID_INPUT),
    ("option sent as a file", M, mp(lambda: multipart([(b"image_a", b"a", PNG), (b"image_b", b"b", PNG),
                                                       (b"ratio", b"r.txt", b"0.5")])), 400, P.INVALID_BODY),
    ("misspelled option", M, mp(lambda: images(PNG, PNG, (b"ratoi", b"0.7"))), 422, P.INVALID_INPUT),
    ("ratio out of range", M, mp(lambda: images(PNG, PNG, (b"ratio", b"1.5"))), 422, P.INVALID_INPUT),
    ("ratio not a number", M, mp(lambda: images(PNG, PNG, (b"ratio", b"abc"))), 422, P.INVALID_INPUT),
    ("ratio NaN", M, mp(lambda: images(PNG, PNG, (b"ratio", b"nan"))), 422, P.INVALID_INPUT),
    ("unknown features", M, mp(lambda: images(PNG, PNG, (b"features", b"orb"))), 422, P.INVALID_INPUT),
    ("max_keypoints zero", M, mp(lambda: images(PNG, PNG, (b"max_keypoints", b"0"))), 422, P.INVALID_INPUT),
    ("max_keypoints over the limit", M, mp(lambda: images(PNG, PNG, (b"max_keypoints", b"10000000"))), 422,
     P.INVALID_INPUT),
    ("dense not a boolean", M, mp(lambda: images(PNG, PNG, (b"dense", b"maybe"))), 422, P.INVALID_INPUT),
    ("negative seed (form)", M, mp(lambda: images(PNG, PNG, (b"seed", b"-3"))), 422, P.INVALID_INPUT),
    ("filter options not JSON", M, mp(lambda: images(PNG, PNG, (b"filter", b"{beta"))), 422, P.INVALID_INPUT),
    ("a field given twice", M, mp(lambda: images(PNG, PNG, (b"ratio", b"0.5"), (b"ratio", b"0.6"))), 422,
     P.INVALID_INPUT),
    ("non-UTF-8 field name", M, mp(lambda: images(PNG, PNG, (b"r\xe4t\xffio", b"0.5"))), 422, P.INVALID_INPUT),
    ("a third file", M, mp(lambda: multipart([(b"image_a", b"a", PNG), (b"image_b", b"b", PNG),
                                              (b"image_c", b"c", PNG)])), 400, P.INVALID_BODY),
    ("huge multipart with many parts", M,
     mp(lambda: images(PNG, PNG, *[(b"f%d" % i, b"x") for i in range(2000)])), 400, P.INVALID_BODY),
    ("upload over the byte limit", M, mp(lambda: images(PNG + b"\x00" * (5 * 1024 * 1024), PNG)), 413, P.TOO_LARGE),
    ("JSON to an image endpoint", M, json_body({"image_a": "x"}), 415, P.UNSUPPORTED_FORMAT),
    ("multipart without a boundary", M, lambda: {"content": b"--x\r\n", "headers": {"content-type":
                                                                                     "multipart/form-data"}},
     400, P.INVALID_BODY),
    ("garbage multipart body", M, lambda: {"content": b"\x00\x01garbage" * 100, "headers": {
        "content-type": "multipart/form-data; boundary=zzz"}}, 400, P.INVALID_BODY),
    ("flow: unknown format", "/v1/flow", mp(lambda: images(PNG, PNG, (b"format", b"jpg"))), 422, P.INVALID_INPUT),
    ("flow: unknown query parameter", "/v1/flow?fromat=npy", mp(lambda: images(PNG, PNG)), 422, P.INVALID_INPUT),
    ("flow: format twice (query and form)", "/v1/flow?format=npy", mp(lambda: images(PNG, PNG, (b"format", b"png"))),
     422, P.INVALID_INPUT),
    ("warp: alpha out of range", "/v1/warp", mp(lambda: images(PNG, PNG, (b"alpha", b"2"))), 422, P.INVALID_INPUT),
    ("warp: unknown interpolation", "/v1/warp", mp(lambda: images(PNG, PNG, (b"interpolation", b"lanczos9"))),
     422, P.INVALID_INPUT),
]


def test_corpus_is_big_enough():
    assert len(CASES) >= 40
    assert len({c[0] for c in CASES}) == len(CASES)


@pytest.mark.parametrize(("name", "path", "build", "status", "type_"), CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_a_clean_4xx(client, name, path, build, status, type_):
    r = client.post(path, **build())
    assert r.status_code == status, f"{name}: {r.status_code} {r.text[:300]}"
    assert r.headers["content-type"].startswith(P.MEDIA_TYPE)
    body = r.json()
    assert body["type"] == type_ and body["status"] == status
    assert body["title"] and body["detail"]
    assert "Traceback" not in r.text and "/work" not in r.text and ".py" not in r.text


@pytest.mark.parametrize("field", ["model_colors", "target_colors", "model_normals"])  # (model, target: the schema)
def test_a_ragged_scan_names_its_field(client, field):
    body = {"model": OK_POINTS, "target": OK_POINTS, field: [[None, 1]]}
    r = client.post(R, **json_body(body)())
    assert r.status_code == 422 and f"`{field}` looks like an organized scan" in r.json()["detail"]


@pytest.mark.parametrize("path", ["/nope", "/v1/filters"])
def test_unknown_route_is_a_problem(client, path):
    r = client.get(path)
    assert r.status_code == 404 and r.headers["content-type"].startswith(P.MEDIA_TYPE)


def test_wrong_method_is_a_problem(client):
    r = client.get("/v1/filter")
    assert r.status_code == 405 and r.headers["content-type"].startswith(P.MEDIA_TYPE)
