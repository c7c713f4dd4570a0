"""``match_bundle``: the match and its files in one answer, and ``MatchBundle.save``.

The answer parsed here is assembled from the real service's own answers for the same pair (``/v1/match``,
``/v1/warp``, ``/v1/flow``, ``/v1/confidence``) in the form of ``POST /v1/match/bundle``; the last test
asks the real endpoint, whose files must be those same bytes.
"""
from __future__ import annotations

import asyncio
import base64
import json
from pathlib import Path
from typing import Any

import httpx2
import numpy as np
import pytest

from reglib_client import (
    AsyncClient,
    Client,
    MalformedResponse,
    MatchBundle,
    MatchResult,
    Transform,
    decode_flow,
    decode_png,
)

from .conftest import Pair

BUNDLE_PATH = "/v1/match/bundle"


def _post(app_client: Any, path: str, pair: Pair, **fields: str) -> bytes:
    from reglib_client import encode_png

    response = app_client.post(path, files={"image_a": ("a.png", encode_png(pair.a)),
                                            "image_b": ("b.png", encode_png(pair.b))}, data=fields)
    assert response.status_code == 200, response.text
    return bytes(response.content)


@pytest.fixture(scope="module")
def answer(app_client: Any, pair: Pair) -> dict[str, Any]:
    """The bundle answer for ``pair``, from the service's single-purpose endpoints."""
    files = {"warped.png": _post(app_client, "/v1/warp", pair),
             "overlay.png": _post(app_client, "/v1/warp", pair, overlay="true", alpha="0.3"),
             "flow.png": _post(app_client, "/v1/flow", pair, format="png"),
             "flow.flo": _post(app_client, "/v1/flow", pair, format="flo"),
             "confidence.png": _post(app_client, "/v1/confidence", pair, format="png")}
    return {"match": json.loads(_post(app_client, "/v1/match", pair)),
            "files": {name: base64.b64encode(content).decode("ascii") for name, content in files.items()}}


class Recorder:
    """A mock transport handler answering ``body`` and keeping the requests."""

    def __init__(self, body: Any) -> None:
        self.body = body
        self.requests: list[httpx2.Request] = []

    def __call__(self, request: httpx2.Request) -> httpx2.Response:
        self.requests.append(request)
        return httpx2.Response(200, json=self.body)


def _check(bundle: MatchBundle, answer: dict[str, Any], pair: Pair, *, exact: tuple[str, ...]) -> None:
    """The bundle of ``pair``: its match, and its files equal to ``answer``'s for the names in ``exact``."""
    assert isinstance(bundle.match, MatchResult)
    assert bundle.match.n_inliers == answer["match"]["n_inliers"] and bundle.match.features == "sift"
    assert sorted(bundle.files) == ["confidence.png", "flow.flo", "flow.png", "overlay.png", "warped.png"]
    for name in exact:
        assert bundle.files[name] == base64.b64decode(answer["files"][name]), name
    assert decode_png(bundle.files["overlay.png"]).shape[:2] == pair.a.shape
    assert decode_png(bundle.files["flow.png"]).shape[:2] == pair.a.shape
    assert decode_png(bundle.files["warped.png"]).shape == pair.a.shape
    flow = decode_flow(bundle.files["flow.flo"])
    assert flow.shape == pair.a.shape + (2,)
    assert np.abs(flow[20:-20, 20:-20] - pair.shift.astype(np.float32)).max() < 1.0
    assert decode_png(bundle.files["confidence.png"]).shape == pair.a.shape


def test_match_bundle_sends_the_match_form_and_reads_the_answer(answer: dict[str, Any], pair: Pair) -> None:
    recorder = Recorder(answer)
    http = httpx2.Client(transport=httpx2.MockTransport(recorder))
    with Client("http://svc", http_client=http) as client:
        bundle = client.match_bundle(pair.a, pair.b, alpha=0.3, seed=4)
    (request,) = recorder.requests
    assert request.method == "POST" and request.url.path == BUNDLE_PATH
    body = request.content
    for part in (b'name="image_a"', b'name="image_b"', b'name="alpha"\r\n\r\n0.3', b'name="seed"\r\n\r\n4'):
        assert part in body, part
    _check(bundle, answer, pair, exact=tuple(answer["files"]))
    assert len(repr(bundle)) < 600 and "bytes>" in repr(bundle)


def test_save_writes_the_layout_of_reglib_match_out(answer: dict[str, Any], pair: Pair, tmp_path: Path) -> None:
    bundle = MatchBundle.from_json(answer)
    written = bundle.save(tmp_path / "new" / "pair-1")
    folder = tmp_path / "new" / "pair-1"
    assert list(written) == [*answer["files"], "transform.json", "match.json"]  # match.json last
    assert sorted(p.name for p in folder.iterdir()) == sorted([*answer["files"], "transform.json", "match.json"])
    assert json.loads((folder / "match.json").read_text()) == answer["match"]
    saved = json.loads((folder / "transform.json").read_text())
    assert saved == answer["match"]["transform"]
    kept = bundle.match.src[bundle.match.inliers]
    np.testing.assert_allclose(Transform.from_dict(saved)(kept), bundle.match.transform(kept))
    for name in answer["files"]:
        assert (folder / name).read_bytes() == bundle.files[name]
    bundle.save(folder)  # again: the same files, replaced
    assert sorted(p.name for p in folder.iterdir()) == sorted(written)
    (tmp_path / "a-file").write_text("x")
    with pytest.raises(ValueError, match="not a folder"):
        bundle.save(tmp_path / "a-file")


def test_a_match_without_a_confidence_map_has_no_confidence_png(answer: dict[str, Any]) -> None:
    files = {k: v for k, v in answer["files"].items() if k != "confidence.png"}
    bundle = MatchBundle.from_json({"match": {**answer["match"], "confidence": None}, "files": files})
    assert "confidence.png" not in bundle.files and bundle.match.confidence is None


@pytest.mark.parametrize(("change", "message"), [
    (lambda a: {"match": a["match"]}, r"missing field\(s\) \['files'\]"),
    (lambda a: {**a, "files": {"warped.png": "not base64!"}}, "'warped.png' is not valid base64"),
    (lambda a: {**a, "files": {"../evil.png": ""}}, "unusable file name '../evil.png'"),
    (lambda a: {**a, "files": {".hidden": ""}}, "unusable file name"),
    (lambda a: {**a, "files": {"match.json": ""}}, "unusable file name 'match.json'"),
    (lambda a: {**a, "files": {"flow.flo": 12}}, "must be a base64 string"),
    (lambda a: {**a, "match": {**a["match"], "shape_a": [3]}}, r"`shape_a` must be \[height, width\]"),
    (lambda a: [a], "bundle must be a JSON object"),
])
def test_a_malformed_bundle_is_a_malformed_response(answer: dict[str, Any], change: Any, message: str) -> None:
    http = httpx2.Client(transport=httpx2.MockTransport(Recorder(change(answer))))
    with Client("http://svc", http_client=http) as client, pytest.raises(MalformedResponse, match=message):
        client.match_bundle(b"a", b"b")


def test_the_async_client_reads_the_same_bundle(answer: dict[str, Any], pair: Pair) -> None:
    async def run() -> MatchBundle:
        http = httpx2.AsyncClient(transport=httpx2.MockTransport(Recorder(answer)))
        async with AsyncClient("http://svc", http_client=http) as client:
            return await client.match_bundle(pair.a, pair.b, alpha=0.3)

    _check(asyncio.run(run()), answer, pair, exact=tuple(answer["files"]))


def test_match_bundle_against_the_service(app_client: Any, answer: dict[str, Any], pair: Pair,
                                          tmp_path: Path) -> None:
    client = Client("http://testserver", http_client=app_client)
    bundle = client.match_bundle(pair.a, pair.b, alpha=0.3)
    assert dict(bundle.match_json) == {**answer["match"], "timings_ms": bundle.match_json["timings_ms"]}
    # each file is the bytes its single endpoint answers for the same form
    _check(bundle, answer, pair, exact=tuple(answer["files"]))
    bundle.save(tmp_path / "pair")
    assert json.loads((tmp_path / "pair" / "match.json").read_text())["n_inliers"] == bundle.match.n_inliers
