"""The parts of the OpenAPI document the routes cannot derive from their signatures.

The image endpoints read their multipart bodies themselves (:mod:`service.uploads`), so their
``requestBody`` is declared here: two binary files, the match request's fields (from the library's
declarations, :func:`reglib.options.option_specs`) and the endpoint's own fields (a pydantic model).
The routes are declared once, at import, with the library's bounds; :func:`state_limits_in_openapi`
makes each app's document state that app's bounds (its settings' ``max_pixels`` and
``max_keypoints_limit``), and, when the app has API keys, the two ways to send one (so that the
Swagger UI's Authorize button works), so no settings are read at import time. :data:`PROBLEM_RESPONSES`
documents the problem answers every compute endpoint may give.
"""
from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from pydantic import BaseModel

from reglib.matching import match_request_specs
from reglib.options import OptionSpec

from .config import Settings
from .limits import form_specs

__all__ = ["PROBLEM_RESPONSES", "FILES", "multipart_openapi", "state_limits_in_openapi"]

#: The file parts of every image endpoint, in order.
FILES = ("image_a", "image_b")


def _problem(description: str) -> dict[str, object]:
    return {"description": description, "content": {"application/problem+json": {"schema": {
        "type": "object", "properties": {"type": {"type": "string"}, "title": {"type": "string"},
                                         "status": {"type": "integer"}, "detail": {"type": "string"}}}}}}


PROBLEM_RESPONSES: dict[int | str, dict[str, object]] = {
    400: _problem("body or image cannot be parsed or decoded"),
    401: _problem("the service has API keys and the request names none of them (see WWW-Authenticate)"),
    413: _problem("over the byte, pixel or point limit, or the job needed more than a worker's memory cap"),
    415: _problem("media type or image format not allowed"),
    422: _problem("invalid input (shapes, NaN, unknown or out-of-range option) or the estimation failed"),
    429: _problem("work queue full, or this API key has its limit of requests in flight; see Retry-After"),
    503: _problem("not ready (starting, replacing a worker, or shutting down); see Retry-After"),
    504: _problem("the computation ran past its time limit"),
    500: _problem("the request crashed a worker process twice (worker-crashed), or a fault of ours (internal)"),
}


def multipart_openapi(fields: type[BaseModel], description: str) -> dict[str, Any]:
    """The ``openapi_extra`` of an image endpoint: its requestBody with the files, the match request's
    fields at the library's bounds (see :func:`state_limits_in_openapi`) and the endpoint's ``fields``."""
    props: dict[str, Any] = {name: {"type": "string", "format": "binary", "description": f"image {name[-1]} (PNG, "
                             "JPEG, TIFF, BMP, WebP, or a 2-D NIfTI, MetaImage or NRRD image)"} for name in FILES}
    for spec in match_request_specs():
        props[spec.name] = _spec_schema(spec)
    body_schema: dict[str, Any] = {"type": "object", "required": list(FILES), "properties": props,
                                   "additionalProperties": False}
    schema = fields.model_json_schema()
    props.update(schema.get("properties", {}))
    if "$defs" in schema:
        body_schema["$defs"] = schema["$defs"]
    return {"requestBody": {"required": True, "description": description, "content": {
        "multipart/form-data": {"schema": body_schema, "encoding": {n: {"contentType": "image/*"} for n in FILES}}}}}


def _spec_schema(spec: OptionSpec) -> dict[str, Any]:
    """The JSON schema of one form field (a form carries text: a "json" field is a string holding JSON)."""
    out: dict[str, Any] = {"description": spec.doc}
    if spec.kind == "json":
        return {"type": "string", "description": spec.doc + " (a JSON object)", "example": '{"linear": "affine"}'}
    if spec.kind == "choice":
        return {"type": "string", "enum": list(spec.choices), "default": spec.default, **out}
    out["type"] = {"bool": "boolean", "int": "integer", "float": "number"}[spec.kind]
    if spec.optional:  # left out or "none": the option's default behaviour (e.g. `band`: the grey rendering)
        out["type"] = [out["type"], "null"]
    out["default"] = spec.default
    cast = int if spec.kind == "int" else float
    if spec.low is not None:
        out["exclusiveMinimum" if spec.low_open else "minimum"] = cast(spec.low)
    if spec.high is not None:
        out["exclusiveMaximum" if spec.high_open else "maximum"] = cast(spec.high)
    return out


def state_limits_in_openapi(app: FastAPI, settings: Settings) -> None:
    """Make ``app``'s OpenAPI document state its own bounds for the match request's form fields.

    The document is built on first use (as FastAPI does) and every multipart body's match fields are
    then replaced by those of :func:`~service.limits.form_specs` for ``settings``: the bounds a
    request to this app is checked against, and ``max_pixels`` defaulting to the app's limit.
    """
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            doc = build()
            fields = {spec.name: _spec_schema(spec) for spec in form_specs(settings)}
            for path in doc.get("paths", {}).values():
                body = path.get("post", {}).get("requestBody", {}).get("content", {}).get("multipart/form-data")
                if body is not None:
                    props = body["schema"]["properties"]
                    props.update({k: v for k, v in fields.items() if k in props})
            if settings.api_keys_file is not None:
                _declare_keys(doc)
            app.openapi_schema = doc
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's way to customize the schema


#: The two ways a request names its API key (:mod:`service.auth`), as OpenAPI security schemes.
SECURITY_SCHEMES = {"bearer": {"type": "http", "scheme": "bearer", "description": "Authorization: Bearer <key>"},
                    "apiKey": {"type": "apiKey", "in": "header", "name": "X-API-Key"}}


def _declare_keys(doc: dict[str, Any]) -> None:
    """Say in ``doc`` that every ``/v1/*`` operation needs an API key, by either scheme."""
    doc.setdefault("components", {})["securitySchemes"] = SECURITY_SCHEMES
    for path, item in doc.get("paths", {}).items():
        if path.startswith("/v1/"):
            for operation in item.values():
                operation["security"] = [{"bearer": []}, {"apiKey": []}]
