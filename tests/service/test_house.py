"""Behaviour the service's structure promises: the OpenAPI document states each app's own limits, the
problem table answers subclasses by their nearest listed class, settings come in as an overridable
dependency, and the match form is parsed once into the request the worker runs."""
from __future__ import annotations

import json
import pickle

import pytest
from fastapi.testclient import TestClient

from reglib import MatchRequest
from reglib.errors import ImageTooLarge, InputError, ReglibError
from service import jobs
from service import problems as P
from service.app import create_app
from service.config import Settings
from service.deps import get_settings
from service.limits import check_points, count_points
from service.pool import NotReady, Overloaded, UndecodableImage, WorkerOutOfMemory

IMAGE_PATHS = ("/v1/match", "/v1/match/bundle", "/v1/warp", "/v1/flow", "/v1/confidence")


def _form_props(doc: dict, path: str) -> dict:
    return doc["paths"][path]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]["properties"]


def test_openapi_states_the_limits_of_the_app_it_belongs_to():
    small = create_app(Settings(workers=1, max_pixels=1000, max_keypoints_limit=77)).openapi()
    default = create_app(Settings(workers=1)).openapi()
    for path in IMAGE_PATHS:
        props = _form_props(small, path)
        assert props["max_pixels"]["maximum"] == 1000 and props["max_pixels"]["default"] == 1000, path
        assert props["max_keypoints"]["maximum"] == 77, path
        # a second app in the same process keeps its own (default) limits
        props = _form_props(default, path)
        assert props["max_pixels"]["maximum"] == Settings.model_fields["max_pixels"].default, path
        assert props["max_keypoints"]["maximum"] == Settings.model_fields["max_keypoints_limit"].default, path


def test_openapi_of_default_settings_keeps_every_form_field_in_order():
    props = _form_props(create_app(Settings(workers=1)).openapi(), "/v1/warp")
    names = list(props)
    assert names[:2] == ["image_a", "image_b"]
    assert names[-3:] == ["overlay", "alpha", "interpolation"]


class _Bigger(ImageTooLarge):
    pass


class _Own(InputError):
    pass


class _Unlisted(ReglibError):
    pass


@pytest.mark.parametrize(("exc", "status", "type_"), [
    (InputError("x"), 422, P.INVALID_INPUT),
    (_Own("x"), 422, P.INVALID_INPUT),                # a subclass answers as its base
    (_Bigger("x"), 413, P.TOO_LARGE),                 # ... as its nearest listed class, not InputError
    (UndecodableImage("x"), 400, P.UNDECODABLE_IMAGE),
    (NotReady("x", 7), 503, P.NOT_READY),             # listed itself, though an Overloaded
    (Overloaded("x", 7), 429, P.OVERLOADED),
    (WorkerOutOfMemory("x"), 413, P.TOO_LARGE),
])
def test_the_problem_table_answers_the_nearest_listed_class(exc, status, type_):
    problem = P.from_library_error(exc)
    assert problem is not None
    assert (problem.status_code, problem.type, problem.detail) == (status, type_, "x")
    assert P.problem_kind(exc).title == json.loads(P.problem_body(status, type_, "x"))["title"]
    if isinstance(exc, Overloaded):
        assert problem.headers == {"Retry-After": "7"}


def test_an_unlisted_exception_has_no_problem_kind():
    assert P.problem_kind(_Unlisted("x")) is None and P.from_library_error(ValueError("x")) is None


def test_a_library_subclass_raised_in_a_route_is_answered_by_the_table():
    app = create_app(Settings(workers=1))

    @app.get("/boom")
    def boom() -> None:
        raise _Bigger("`image_a` is too big")

    r = TestClient(app, raise_server_exceptions=False).get("/boom")
    assert r.status_code == 413 and r.headers["content-type"] == P.MEDIA_TYPE
    assert r.json() == {"type": P.TOO_LARGE, "title": "The request is over a size limit", "status": 413,
                        "detail": "`image_a` is too big"}


def test_settings_are_a_dependency_tests_may_override():
    app = create_app(Settings(workers=1))   # no lifespan: the pool never starts, the limit answers first
    app.dependency_overrides[get_settings] = lambda: Settings(workers=1, max_points=2)
    r = TestClient(app, raise_server_exceptions=False).post(
        "/v1/filter", json={"src": [[0.0, 0.0]] * 3, "dst": [[0.0, 0.0]] * 3})
    assert r.status_code == 413 and r.json()["detail"] == "`src` has 3 points, over the limit of 2"


def test_point_limits_count_the_pixels_of_an_organized_scan():
    scan = [[[0.0, 0.0, 1.0], None], [None, None]]
    assert count_points(scan) == 4 and count_points([[0.0, 1.0], [2.0, 3.0]]) == 2
    check_points(Settings(workers=1, max_points=4), model=scan)
    with pytest.raises(P.Problem, match="`model` has 4 points, over the limit of 3"):
        check_points(Settings(workers=1, max_points=3), target=[[0.0, 0.0]], model=scan)


def test_a_parsed_match_request_travels_to_a_worker_unchanged():
    request = MatchRequest.from_fields({"ratio": "0.9", "dense": "false", "filter": '{"beta": 0.5}', "seed": "3"})
    again = pickle.loads(pickle.dumps(request))
    assert again == request and again.options == request.options and again.to_fields() == request.to_fields()


@pytest.mark.slow
def test_the_service_answers_what_the_job_computes_on_the_parsed_request(client, png_pair, settings):
    a, b = png_pair
    files = {"image_a": ("a.png", a, "image/png"), "image_b": ("b.png", b, "image/png")}
    r = client.post("/v1/match", files=files, data={"ratio": "0.85", "dense": "false", "seed": "2"})
    assert r.status_code == 200, r.text
    request = MatchRequest.from_fields({"ratio": "0.85", "dense": "false", "seed": "2",
                                        "max_pixels": settings.max_pixels}, what="form")
    expected = jobs.match_job(a, b, request)
    got = r.json()
    for body in (got, expected):
        body.pop("timings_ms")
    assert got == expected
