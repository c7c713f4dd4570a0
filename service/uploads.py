"""Reading the multipart requests of the image endpoints: two files plus option fields.

Checks here run on the event loop and are cheap (no decoding): parts and field names, option
values (pydantic), and for each image its format from the magic bytes and its size from the
header (a decompression bomb is refused before any worker decodes it).
"""
from __future__ import annotations

import json
from typing import Any, TypeVar

from fastapi import Request
from pydantic import BaseModel, ValidationError
from starlette.datastructures import UploadFile

from reglib.io import image_format, image_size

from .config import Settings
from .problems import (
    INVALID_BODY,
    INVALID_INPUT,
    TOO_LARGE,
    UNDECODABLE_IMAGE,
    UNSUPPORTED_FORMAT,
    Problem,
)

__all__ = ["read_upload", "multipart_openapi", "FILES"]

M = TypeVar("M", bound=BaseModel)
FILES = ("image_a", "image_b")
_MAX_FIELD_BYTES = 64 * 1024
JSON_FIELDS = ("filter", "dense_filter")


async def read_upload(request: Request, settings: Settings, fields: type[M],
                      extra: dict[str, str] | None = None) -> tuple[bytes, bytes, M]:
    """Return the two images' bytes (format and size checked) and the validated option fields.

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
        allowed = set(fields.model_fields)
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
        for key in JSON_FIELDS:
            if isinstance(values.get(key), str):
                try:
                    values[key] = json.loads(values[key])
                except ValueError:
                    raise Problem(422, INVALID_INPUT, f"`{key}` must be a JSON object of estimator options") from None
        try:
            options = fields.model_validate(values)
        except ValidationError as exc:
            errors = [{"loc": [str(p) for p in e["loc"]], "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
            summary = "; ".join(f"{'.'.join(e['loc'])}: {e['msg']}" for e in errors[:5])
            raise Problem(422, INVALID_INPUT, summary, extra={"errors": errors}) from None
        max_kp = getattr(options, "max_keypoints", None)
        if max_kp is not None and max_kp > settings.max_keypoints_limit:
            raise Problem(422, INVALID_INPUT, f"`max_keypoints` must be <= {settings.max_keypoints_limit}, got {max_kp}")
        data = [await files[name].read() for name in FILES]
    finally:
        await form.close()
    for name, blob in zip(FILES, data):
        check_image(name, blob, settings)
    return data[0], data[1], options


def check_image(name: str, data: bytes, settings: Settings) -> None:
    """Format from the magic bytes and pixels from the header, before any decoding."""
    if not data:
        raise Problem(400, UNDECODABLE_IMAGE, f"`{name}` is empty (0 bytes)")
    fmt = image_format(data)
    if fmt is None:
        raise Problem(400, UNDECODABLE_IMAGE, f"`{name}` is not an image in a format known here "
                      f"(allowed: {', '.join(settings.allowed_formats)})")
    if fmt not in settings.allowed_formats:
        raise Problem(415, UNSUPPORTED_FORMAT, f"`{name}` is {fmt.upper()}; allowed formats are "
                      f"{', '.join(f.upper() for f in settings.allowed_formats)}")
    size = image_size(data)
    if size is not None:
        w, h = size
        if w * h > settings.max_pixels:
            raise Problem(413, TOO_LARGE, f"`{name}` is {w}x{h} = {w * h} pixels (from its header), over the "
                          f"limit of {settings.max_pixels}")
        if w == 0 or h == 0:
            raise Problem(400, UNDECODABLE_IMAGE, f"`{name}` has an empty size {w}x{h} in its header")


def multipart_openapi(fields: type[BaseModel], description: str) -> dict[str, Any]:
    """The OpenAPI requestBody of an image endpoint: two binary files plus ``fields`` as form fields."""
    schema = fields.model_json_schema()
    props = {name: {"type": "string", "format": "binary", "description": f"image {name[-1]} (PNG, JPEG, TIFF, "
                    "BMP or WebP)"} for name in FILES}
    for name, prop in schema.get("properties", {}).items():
        prop = dict(prop)
        if name in JSON_FIELDS:
            prop = {"type": "string", "description": prop.get("description", "") + " (a JSON object)",
                    "example": '{"linear": "affine"}'}
        props[name] = prop
    body_schema = {"type": "object", "required": list(FILES), "properties": props,
                   "additionalProperties": False}
    if "$defs" in schema:
        body_schema["$defs"] = schema["$defs"]
    return {"requestBody": {"required": True, "description": description, "content": {
        "multipart/form-data": {"schema": body_schema, "encoding": {n: {"contentType": "image/*"} for n in FILES}}}}}
