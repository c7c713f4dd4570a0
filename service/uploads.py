"""Reading the multipart requests of the image endpoints: two files plus option fields.

Checks here run on the event loop and are cheap (no decoding): parts and field names, the match
request's fields by the library's own parser (:class:`reglib.MatchRequest`; the form fields and
their OpenAPI schema are derived from the library's declarations, with the service's tighter
bounds on ``max_pixels`` and ``max_keypoints``), an endpoint's own fields (pydantic), and for each
image its format from the magic bytes and its size from the header (a decompression bomb is
refused before any worker decodes it).
"""
from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from fastapi import Request
from pydantic import BaseModel, ValidationError
from starlette.datastructures import UploadFile

from reglib import MatchRequest
from reglib.errors import ImageTooLarge, InputError, UnsupportedFormat
from reglib.io import check_image_header
from reglib.options import OptionSpec, parse_fields
from reglib.request import match_request_specs

from .config import Settings
from .problems import (
    INVALID_BODY,
    INVALID_INPUT,
    TOO_LARGE,
    UNDECODABLE_IMAGE,
    UNSUPPORTED_FORMAT,
    Problem,
)

__all__ = ["read_upload", "multipart_openapi", "form_specs", "use_settings_in_openapi", "FILES"]

M = TypeVar("M", bound=BaseModel)
FILES = ("image_a", "image_b")
_MAX_FIELD_BYTES = 64 * 1024


def form_specs(settings: Settings) -> tuple[OptionSpec, ...]:
    """The match request's fields as this service takes them: the library's, with the settings'
    bounds on ``max_pixels`` and ``max_keypoints`` (and ``max_pixels`` defaulting to the limit)."""
    tighter = {"max_pixels": settings.max_pixels, "max_keypoints": settings.max_keypoints_limit}
    out = []
    for spec in match_request_specs():
        if spec.name in tighter:
            spec = spec.bounded(tighter[spec.name])
            if spec.name == "max_pixels":
                spec = dataclasses.replace(spec, default=settings.max_pixels)
        out.append(spec)
    return tuple(out)


async def read_upload(request: Request, settings: Settings, fields: type[M] | None = None,
                      extra: dict[str, str] | None = None) -> tuple[bytes, bytes, MatchRequest, M | None]:
    """Return the two images' bytes (format and size checked), the match request, and the
    endpoint's own fields (``fields``, a pydantic model; None when the endpoint has none).

    ``extra`` holds option values from elsewhere (the query string); a name given twice is a 422.
    """
    try:
        form = await request.form(max_files=len(FILES), max_fields=settings.max_form_parts,
                                  max_part_size=_MAX_FIELD_BYTES)
    except Problem:
        raise
    except Exception as exc:  # malformed multipart: starlette raises HTTPException(400) or a parser error
        raise Problem(400, INVALID_BODY, f"the multipart body cannot be parsed: {getattr(exc, 'detail', exc)}") from None
    try:
        values: dict[str, Any] = dict(extra or {})
        files: dict[str, UploadFile] = {}
        specs = form_specs(settings)
        own = set(fields.model_fields) if fields is not None else set()
        allowed = {spec.name for spec in specs} | own
        for key in set(form.keys()):
            items = form.getlist(key)
            if len(items) != 1:
                raise Problem(422, INVALID_INPUT, f"field `{key}` is given {len(items)} times")
            item = items[0]
            if key in FILES:
                if not isinstance(item, UploadFile):
                    raise Problem(422, INVALID_INPUT, f"`{key}` must be a file upload, got a text field")
                files[key] = item
            elif key not in allowed:
                raise Problem(422, INVALID_INPUT, f"unknown field `{key}`; the fields of {request.url.path} are "
                              f"{sorted([*FILES, *allowed])}")
            elif isinstance(item, UploadFile):
                raise Problem(422, INVALID_INPUT, f"`{key}` must be a text field, got a file")
            elif key in values:
                raise Problem(422, INVALID_INPUT, f"`{key}` is given both in the query and in the form")
            else:
                values[key] = item
        missing = [name for name in FILES if name not in files]
        if missing:
            raise Problem(422, INVALID_INPUT, f"missing file(s) {missing}: upload `image_a` and `image_b`")
        own_values = {k: v for k, v in values.items() if k in own}
        try:
            parsed = parse_fields(specs, {k: v for k, v in values.items() if k not in own}, "form")
            parsed.setdefault("max_pixels", settings.max_pixels)
            match_request = MatchRequest.from_fields(parsed, what="form")
        except InputError as exc:
            raise Problem(422, INVALID_INPUT, str(exc)) from None
        options = None
        if fields is not None:
            try:
                options = fields.model_validate(own_values)
            except ValidationError as exc:
                errors = [{"loc": [str(p) for p in e["loc"]], "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
                summary = "; ".join(f"{'.'.join(e['loc'])}: {e['msg']}" for e in errors[:5])
                raise Problem(422, INVALID_INPUT, summary, extra={"errors": errors}) from None
        data = [await files[name].read() for name in FILES]
    finally:
        await form.close()
    for name, blob in zip(FILES, data):
        check_image(name, blob, settings)
    return data[0], data[1], match_request, options


def check_image(name: str, data: bytes, settings: Settings) -> None:
    """Format from the magic bytes and pixels from the header, before any decoding
    (:func:`reglib.io.check_image_header`, its errors as problem answers)."""
    try:
        check_image_header(data, max_pixels=settings.max_pixels, allowed=tuple(settings.allowed_formats), name=name)
    except UnsupportedFormat as exc:
        raise Problem(415, UNSUPPORTED_FORMAT, str(exc)) from None
    except ImageTooLarge as exc:
        raise Problem(413, TOO_LARGE, str(exc)) from None
    except InputError as exc:
        raise Problem(400, UNDECODABLE_IMAGE, str(exc)) from None


def multipart_openapi(settings: Settings, fields: type[BaseModel] | None, description: str) -> dict[str, Any]:
    """The OpenAPI requestBody of an image endpoint: two binary files, the match request's fields
    (from the library's declarations, :func:`form_specs`) and the endpoint's own ``fields``."""
    props: dict[str, Any] = {name: {"type": "string", "format": "binary", "description": f"image {name[-1]} (PNG, "
                             "JPEG, TIFF, BMP or WebP)"} for name in FILES}
    for spec in form_specs(settings):
        props[spec.name] = _spec_schema(spec)
    body_schema: dict[str, Any] = {"type": "object", "required": list(FILES), "properties": props,
                                   "additionalProperties": False}
    if fields is not None:
        schema = fields.model_json_schema()
        props.update(schema.get("properties", {}))
        if "$defs" in schema:
            body_schema["$defs"] = schema["$defs"]
    return {"requestBody": {"required": True, "description": description, "content": {
        "multipart/form-data": {"schema": body_schema, "encoding": {n: {"contentType": "image/*"} for n in FILES}}}}}


def _spec_schema(spec: OptionSpec) -> dict[str, Any]:
    out: dict[str, Any] = {"description": spec.doc}
    if spec.kind == "json":
        return {"type": "string", "description": spec.doc + " (a JSON object)", "example": '{"linear": "affine"}'}
    if spec.kind == "choice":
        return {"type": "string", "enum": list(spec.choices), "default": spec.default, **out}
    out["type"] = {"bool": "boolean", "int": "integer", "float": "number"}[spec.kind]
    out["default"] = spec.default
    cast = int if spec.kind == "int" else float
    if spec.low is not None:
        out["exclusiveMinimum" if spec.low_open else "minimum"] = cast(spec.low)
    if spec.high is not None:
        out["exclusiveMaximum" if spec.high_open else "maximum"] = cast(spec.high)
    return out


def use_settings_in_openapi(app: Any, settings: Settings) -> None:
    """Make the app's OpenAPI document state this app's bounds (``max_pixels``, ``max_keypoints``) for
    the match request's form fields (the routes' declarations are made with the default settings)."""
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
            app.openapi_schema = doc
        return app.openapi_schema  # type: ignore[no-any-return]

    app.openapi = openapi
