"""The client against the real app in-process (its TestClient passed as ``http_client``).

Answers are compared with the library's own for the same inputs and seed (the service's contract),
and with ground truth made by construction (a known shift between two crops of one texture).
"""
from __future__ import annotations

import asyncio
import io
from typing import Any

import numpy as np
import pytest

import reglib
from reglib_client import (
    AsyncClient,
    Client,
    FilterResult,
    FlowResult,
    InvalidInput,
    MatchResult,
    RegisterResult,
    TooLarge,
    WarpResult,
    encode_png,
)
from service import problems

from .conftest import SETTINGS, Pair, shifted_pair, textured


@pytest.fixture(scope="module")
def client(app_client: Any) -> Client:
    return Client("http://testserver", http_client=app_client)


def synthetic_matches(seed: int, n: int = 80, n_out: int = 20) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Putative matches under a smooth non-rigid map, with ``n_out`` random outliers at the end."""
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 400, (n, 2))
    dst = src * [1.05, 0.97] + [12.0, -4.0] + 6.0 * np.sin(src[:, ::-1] / 90.0)
    dst[n - n_out:] = rng.uniform(0, 400, (n_out, 2))
    truth = np.zeros(n, bool)
    truth[: n - n_out] = True
    return src, dst, truth


def test_health(client: Client) -> None:
    health = client.health()
    assert health.live and health.ready
    assert health.detail["workers"] == SETTINGS["workers"]


# ------------------------------------------------------------------------------------ /v1/filter
def test_filter_finds_the_true_matches_and_equals_the_library(client: Client) -> None:
    src, dst, truth = synthetic_matches(1)
    result = client.filter(src, dst)
    assert isinstance(result, FilterResult) and result.converged and result.reason is None
    assert result.n_matches == len(src) and result.src.shape == (len(src), 2)
    np.testing.assert_array_equal(result.inlier_mask, truth)
    assert np.all(np.diff(result.inliers) > 0) and result.seed == 0
    residual = np.linalg.norm(result.transform(src[truth]) - dst[truth], axis=1)
    assert residual.mean() < 2.5 and residual.max() < 8.0  # outliers are off by ~150 px on average
    assert result.sigma is not None and result.n_iter is not None and "filter" in result.timings_ms

    library = reglib.filter_matches(src, dst, rng=0)
    np.testing.assert_array_equal(result.inlier_mask, library.inliers)
    np.testing.assert_allclose(result.scores, library.scores, rtol=1e-9, atol=1e-12)
    fresh = np.random.default_rng(9).uniform(0, 400, (50, 2))  # new points, evaluated without the server
    np.testing.assert_allclose(result.transform(fresh), library.transform(fresh), rtol=1e-9, atol=1e-9)


def test_filter_method_seed_and_options_are_sent(client: Client) -> None:
    src, dst, truth = synthetic_matches(2)
    result = client.filter(src, dst, method="vfc", seed=7)
    assert result.seed == 7
    np.testing.assert_array_equal(result.inlier_mask, reglib.filter_matches(src, dst, method="vfc", rng=7).inliers)
    affine = client.filter(src, dst, linear="affine", n_centers=10)
    library = reglib.filter_matches(src, dst, options={"linear": "affine", "n_centers": 10}, rng=0)
    assert affine.transform.linear_kind == "affine" and affine.transform.n_centers == library.transform.n_centers


def test_filter_too_few_matches_is_an_answer(client: Client) -> None:
    result = client.filter(np.zeros((0, 2)), np.zeros((0, 2)))
    assert not result.converged and result.reason and result.n_matches == 0
    assert result.inliers.shape == (0,) and result.src.shape == (0, 2)
    np.testing.assert_array_equal(result.transform([[3.0, 4.0]]), [[3.0, 4.0]])


def test_filter_invalid_input_is_a_typed_error(client: Client) -> None:
    with pytest.raises(InvalidInput) as info:
        client.filter([[0.0, 0.0], [1.0, 2.0]], [[0.0, 0.0]])
    assert info.value.status == 422 and info.value.type == problems.INVALID_INPUT
    with pytest.raises(InvalidInput, match="betta") as info:
        client.filter(*synthetic_matches(3)[:2], betta=0.5)  # misspelled option: never silently ignored
    assert info.value.status == 422


def test_filter_over_the_point_limit_is_too_large(client: Client, app_client: Any) -> None:
    limit = app_client.app.state.settings.max_points
    big = np.zeros((limit + 1, 2))
    with pytest.raises(TooLarge) as info:
        client.filter(big, big)
    assert info.value.status == 413 and info.value.type == problems.TOO_LARGE


# ------------------------------------------------------------------------------------ /v1/register
def test_register_moves_the_model_onto_the_target(client: Client) -> None:
    rng = np.random.default_rng(4)
    model = rng.uniform(-1, 1, (60, 2))
    target = model * 1.1 + [0.3, -0.2]
    result = client.register(model, target, seed=1)
    assert isinstance(result, RegisterResult) and result.registered.shape == (60, 2)
    assert result.correspondence.shape == (60,) and result.seed == 1
    assert np.abs(result.registered - target).mean() < 0.05
    np.testing.assert_allclose(result.transform(model), result.registered, rtol=1e-9, atol=1e-9)
    assert result.matrix is None  # l2e is non-rigid
    with pytest.raises(InvalidInput):
        client.register(model, rng.uniform(-1, 1, (30, 3)))


def test_a_rigid_registration_carries_its_matrix(client: Client) -> None:
    rng = np.random.default_rng(5)
    model = rng.normal(size=(80, 3)) * [3.0, 2.0, 1.0]
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    target = model @ rot.T + [20.0, -5.0, 3.0]
    result = client.register(model, target, method="cpd-rigid", seed=0)
    expected = reglib.register_points(model, target, method="cpd-rigid", rng=0)
    assert result.matrix.shape == (4, 4)
    np.testing.assert_allclose(result.matrix, expected.matrix, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(result.matrix[:3], np.c_[rot, [20.0, -5.0, 3.0]], atol=1e-6)
    np.testing.assert_allclose(model @ result.matrix[:3, :3].T + result.matrix[:3, 3], result.registered, atol=1e-6)


def test_uint8_colours_are_sent_as_the_service_takes_them(client: Client) -> None:
    rng = np.random.default_rng(6)
    xy = rng.uniform(-1, 1, (200, 2))
    model = np.c_[xy, 0.3 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1])]
    target = model + [0.1, -0.05, 0.02]
    rgb8 = rng.integers(0, 256, (200, 3)).astype(np.uint8)
    result = client.register(model, target, method="color-gmm", seed=0, model_colors=rgb8, target_colors=rgb8)
    expected = reglib.register_points(model, target, method="color-gmm", rng=0, model_colors=rgb8 / 255.0,
                                      target_colors=rgb8 / 255.0)
    np.testing.assert_allclose(result.registered, expected.registered, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(result.registered, target, atol=1e-3)


# ------------------------------------------------------------------------------------ images
def _check_match(result: MatchResult, pair: Pair) -> None:
    assert result.converged and result.n_inliers >= 8
    kept_a = result.src[result.inliers]
    assert np.abs(result.dst[result.inliers] - (kept_a + pair.shift)).max() < 1.5
    assert np.abs(result.transform(kept_a) - (kept_a + pair.shift)).max() < 1.0


def test_match_arrays_equal_the_library(client: Client, pair: Pair) -> None:
    result = client.match(pair.a, pair.b)
    _check_match(result, pair)
    assert result.seed == 0 and result.timings_ms
    library = reglib.match_images(pair.a, pair.b, rng=0)
    assert result.n_matches == library.n_matches
    np.testing.assert_array_equal(result.inlier_mask, library.inliers)
    np.testing.assert_allclose(result.transform(result.src), library.transform(result.src), rtol=1e-9, atol=1e-9)


def test_match_carries_every_field_the_service_sends(client: Client, app_client: Any, pair: Pair) -> None:
    raw = app_client.post("/v1/match", files={"image_a": ("a.png", encode_png(pair.a)),
                                              "image_b": ("b.png", encode_png(pair.b))}).json()
    fields = set(MatchResult.__dataclass_fields__)
    assert set(raw) <= fields, f"MatchResult drops {sorted(set(raw) - fields)}"
    result = client.match(pair.a, pair.b)
    library = reglib.match_images(pair.a, pair.b, rng=0)
    assert result.features == library.features == raw["features"] == "sift"
    assert result.method == "l2e" and result.shape_a == pair.a.shape == result.shape_b
    assert result.n_dense == library.n_dense > 0  # the dense stage ran by default and added matches
    assert result.fold_fraction == pytest.approx(library.fold_fraction, abs=1e-12)
    assert 0.0 <= result.fold_fraction < 0.01  # a shift does not fold
    assert result.confidence is not None and library.confidence_summary is not None
    assert set(result.confidence) == {"mean", "supported_share", "overlap", "dense"}
    for key, value in library.confidence_summary.items():
        if isinstance(value, str):  # "dense": what became of the dense stage
            assert result.confidence[key] == value, key
        else:
            assert result.confidence[key] == pytest.approx(value, rel=1e-9), key
    assert 0.5 < result.confidence["mean"] <= 1.0


def test_features_auto_says_which_path_ran(client: Client, pair: Pair) -> None:
    auto = client.match(pair.a, pair.b, features="auto", dense=False)
    library = reglib.match_images(pair.a, pair.b, options={"dense": False}, features="auto", rng=0)
    assert auto.features == library.features and auto.features in ("sift", "multimodal")
    assert auto.n_dense == 0


def test_reprs_are_short_and_show_the_key_numbers(client: Client, pair: Pair) -> None:
    match = client.match(pair.a, pair.b)
    text = repr(match)
    assert len(text) < 400, text
    for part in (f"n_matches={match.n_matches}", f"n_inliers={match.n_inliers}", "features='sift'",
                 f"shape_a={pair.a.shape}", f"n_dense={match.n_dense}", "'mean': ", "Transform(dim=2"):
        assert part in text, part
    assert "array" not in text and "[[" not in text
    flow = client.flow(pair.a, pair.b)
    assert repr(flow) == (f"FlowResult(flow=<array 200x280x2 float32>, media_type={flow.media_type!r}, "
                          f"content=<{len(flow.content)} bytes>)")
    src, dst, _ = synthetic_matches(1)
    assert len(repr(client.filter(src, dst))) < 300


def test_match_accepts_paths_bytes_and_file_objects(client: Client, pair: Pair, tmp_path: Any) -> None:
    path_a = tmp_path / "a.png"
    path_a.write_bytes(encode_png(pair.a))
    b_bytes = encode_png(np.stack([pair.b] * 3, axis=2))  # colour works too
    by_path = client.match(path_a, b_bytes)
    by_str_and_file = client.match(str(path_a), io.BytesIO(b_bytes))
    with open(path_a, "rb") as handle:
        by_handle = client.match(handle, pair.b)
    for result in (by_path, by_str_and_file, by_handle):
        _check_match(result, pair)
    np.testing.assert_array_equal(by_path.inliers, by_str_and_file.inliers)


def test_match_options_and_their_errors(client: Client, pair: Pair) -> None:
    result = client.match(pair.a, pair.b, max_keypoints=300, ratio=0.8, method="vfc", seed=5)
    _check_match(result, pair)
    assert result.seed == 5
    with pytest.raises(InvalidInput, match="max_keypointz") as info:
        client.match(pair.a, pair.b, max_keypointz=300)
    assert info.value.status == 422 and info.value.type == problems.INVALID_INPUT
    with pytest.raises(InvalidInput) as info:
        client.match(pair.a, pair.b, ratio=1.5)
    assert info.value.status == 422


def test_undecodable_and_too_large_images(client: Client, pair: Pair) -> None:
    broken = encode_png(pair.a)[:200]
    with pytest.raises(InvalidInput) as info:
        client.match(broken, pair.b)
    assert info.value.status == 400 and info.value.type == problems.UNDECODABLE_IMAGE
    huge = np.zeros((600, 600), np.uint8)  # 360 000 pixels, over this app's max_pixels
    with pytest.raises(TooLarge) as info:
        client.match(huge, pair.b)
    assert info.value.status == 413 and info.value.type == problems.TOO_LARGE


def test_featureless_images_are_an_answer(client: Client) -> None:
    flat = np.full((64, 64), 128, np.uint8)
    result = client.match(flat, flat)
    assert not result.converged and result.reason and result.n_inliers == 0
    assert result.src.shape == (result.n_matches, 2)


def test_warp_overlays_image_a(client: Client, pair: Pair) -> None:
    result = client.warp(pair.a, pair.b)
    assert isinstance(result, WarpResult) and result.media_type == "image/png"
    assert result.image.shape == pair.a.shape and result.image.dtype == np.uint8
    inner = (slice(15, -15), slice(15, -15))  # away from the border that b does not cover
    diff = np.abs(result.image[inner].astype(float) - pair.a[inner].astype(float))
    assert diff.mean() < 3.0
    overlay = client.warp(pair.a, pair.b, overlay=True, alpha=0.5)
    assert overlay.image.shape[:2] == pair.a.shape


def test_flow_as_npy_and_flo(client: Client, pair: Pair) -> None:
    npy = client.flow(pair.a, pair.b)
    flo = client.flow(pair.a, pair.b, format="flo")
    for result in (npy, flo):
        assert isinstance(result, FlowResult) and result.flow.shape == pair.a.shape + (2,)
        assert result.flow.dtype == np.float32
    assert npy.media_type.startswith("application/x-npy") and flo.content.startswith(b"PIEH")
    np.testing.assert_array_equal(npy.flow, flo.flow)
    inner = npy.flow[20:-20, 20:-20]
    assert np.abs(inner - pair.shift.astype(np.float32)).max() < 1.0


# ------------------------------------------------------------------------------------ match_many
def test_match_many_yields_every_pair_and_reports_failures(client: Client) -> None:
    pairs = {f"pair{seed}": (p.a, p.b) for seed, p in ((s, shifted_pair(s)) for s in (1, 2, 3))}
    pairs["broken"] = (b"this is not an image", textured(4)[:100, :100])
    seen: list[tuple[int, int | None]] = []
    outcomes = list(client.match_many(pairs, concurrency=2, progress=lambda done, total: seen.append((done, total))))
    assert sorted(o.key for o in outcomes) == sorted(pairs)
    by_key = {o.key: o for o in outcomes}
    assert not by_key["broken"].ok and isinstance(by_key["broken"].error, InvalidInput)
    assert by_key["broken"].error.status == 400
    for key in ("pair1", "pair2", "pair3"):
        assert by_key[key].ok
        _check_match(by_key[key].result, shifted_pair(int(key[-1])))
    assert seen == [(1, 4), (2, 4), (3, 4), (4, 4)]


def test_match_many_reads_a_generator_lazily(client: Client) -> None:
    drawn: list[int] = []

    def pairs() -> Any:
        for seed in (5, 6, 7):
            drawn.append(seed)
            p = shifted_pair(seed)
            yield p.a, p.b

    outcomes = client.match_many(pairs(), concurrency=1, progress=False)
    first = next(outcomes)
    assert first.key == 0 and first.ok and len(drawn) <= 2  # one in flight, at most one more drawn
    rest = list(outcomes)
    assert sorted(o.key for o in rest) == [1, 2] and all(o.ok for o in rest)


def test_match_many_with_tqdm(client: Client, pair: Pair, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("tqdm")
    outcomes = list(client.match_many([(pair.a, pair.b), (pair.b, pair.a)], concurrency=2))
    assert [o.ok for o in outcomes] == [True, True]
    assert "2/2" in capsys.readouterr().err


# ------------------------------------------------------------------------------------ AsyncClient
def test_async_client_against_the_app(pair: Pair) -> None:
    import httpx2

    from service.app import create_app
    from service.config import Settings

    async def run() -> None:
        app = create_app(Settings(**SETTINGS))
        async with app.router.lifespan_context(app):
            http = httpx2.AsyncClient(transport=httpx2.ASGITransport(app=app))
            async with AsyncClient("http://testserver", http_client=http) as client:
                assert (await client.health()).ready
                src, dst, truth = synthetic_matches(1)
                np.testing.assert_array_equal((await client.filter(src, dst)).inlier_mask, truth)
                _check_match(await client.match(pair.a, pair.b), pair)
                assert (await client.flow(pair.a, pair.b)).flow.shape == pair.a.shape + (2,)
                assert (await client.warp(pair.a, pair.b)).image.shape == pair.a.shape
                with pytest.raises(InvalidInput):
                    await client.match(pair.a, pair.b, colour=True)
                outcomes = [o async for o in client.match_many({"good": (pair.a, pair.b), "bad": (b"xx", pair.b)},
                                                               concurrency=2, progress=False)]
                assert {o.key: o.ok for o in outcomes} == {"good": True, "bad": False}
            await http.aclose()

    asyncio.run(run())
