"""Reading the multipart requests of the image endpoints: two files plus option fields.

Checks here run on the event loop and are cheap (no decoding): parts and field names; the match
request's fields, parsed once by the library (:meth:`reglib.MatchRequest.from_fields`) and then held
to the service's tighter bounds on ``max_pixels`` and ``max_keypoints``
(:func:`~service.limits.check_form_bounds`); an endpoint's own fields (pydantic); and for each image
its format from the magic bytes and its size from the header (a decompression bomb is refused
before any worker decodes it). The parsed :class:`~reglib.MatchRequest` is what the worker gets.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from fastapi import Request
from pydantic import BaseModel, ValidationError
from starlette.datastructures import FormData, UploadFile

from reglib import MatchRequest
from reglib.errors import ImageTooLarge, InputError, UnsupportedFormat
from reglib.io import check_image_header
from reglib.options import nearest_names

from .config import Settings
from .limits import check_form_bounds, form_specs
from .openapi import FILES
from .pool import UndecodableImage
from .problems import INVALID_BODY, INVALID_INPUT, Problem

__all__ = ["ImageUpload", "read_upload", "check_image"]

M = TypeVar("M", bound=BaseModel)
_MAX_FIELD_BYTES = 64 * 1024


@dataclass(frozen=True, eq=False)
class ImageUpload(Generic[M]):
    """A checked image request: both images' bytes (format and size checked, not decoded), the parsed
    match request and the endpoint's own fields."""

    image_a: bytes
    image_b: bytes
    request: MatchRequest
    fields: M


async def read_upload(request: Request, settings: Settings, fields: type[M],
                      extra: dict[str, str] | None = None) -> ImageUpload[M]:
    """Read and check an image endpoint's multipart body; ``fields`` is the endpoint's own form model.

    ``extra`` holds option values from elsewhere (the query string); a name given twice is a 422.

    Raises
    ------
    Problem
        400 for a body that is not multipart, 422 for a field that is unknown, repeated, out of range
        or missing, 413 / 415 for an image over the pixel limit or in a format not allowed.
    UndecodableImage
        An image whose header cannot be read (answered 400 by the problem table).
    """
    try:
        form = await request.form(max_files=len(FILES), max_fields=settings.max_form_parts,
                                  max_part_size=_MAX_FIELD_BYTES)
    except Problem:
        raise
    except Exception as exc:  # malformed multipart: starlette raises HTTPException(400) or a parser error
        detail = getattr(exc, "detail", exc)
        raise Problem(400, INVALID_BODY, f"the multipart body cannot be parsed: {detail}") from None
    try:
        own = set(fields.model_fields)
        values, files = _sort_parts(form, {spec.name for spec in form_specs(settings)} | own, extra,
                                    request.url.path)
        try:
            match_values = {k: v for k, v in values.items() if k not in own}
            match_values.setdefault("max_pixels", settings.max_pixels)
            match_request = MatchRequest.from_fields(match_values, what="form")
        except InputError as exc:
            raise Problem(422, INVALID_INPUT, str(exc)) from None
        check_form_bounds(match_request, settings)
        own_fields = _validate(fields, {k: v for k, v in values.items() if k in own})
        data = [await files[name].read() for name in FILES]
    finally:
        await form.close()
    for name, blob in zip(FILES, data, strict=True):
        check_image(name, blob, settings)
    return ImageUpload(data[0], data[1], match_request, own_fields)


def _sort_parts(form: FormData, allowed: set[str], extra: dict[str, str] | None,
                path: str) -> tuple[dict[str, Any], dict[str, UploadFile]]:
    """The form's text fields (with ``extra``) and its two files; a part that is not one of ``allowed``
    or of :data:`~service.openapi.FILES`, repeated, or of the wrong kind is a 422."""
    values: dict[str, Any] = dict(extra or {})
    files: dict[str, UploadFile] = {}
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
            raise Problem(422, INVALID_INPUT, _unknown_field(key, [*FILES, *allowed], path))
        elif isinstance(item, UploadFile):
            raise Problem(422, INVALID_INPUT, f"`{key}` must be a text field, got a file")
        elif key in values:
            raise Problem(422, INVALID_INPUT, f"`{key}` is given both in the query and in the form")
        else:
            values[key] = item
    missing = [name for name in FILES if name not in files]
    if missing:
        raise Problem(422, INVALID_INPUT, f"missing file(s) {missing}: upload `image_a` and `image_b`")
    return values, files


def _unknown_field(key: str, names: list[str], path: str) -> str:
    """The 422's words: the nearest field names when some are close (as the CLI answers ``--ratoi``), else all."""
    close = nearest_names(key, names)
    if close:
        return (f"unknown field `{key}`: did you mean {' or '.join(f'`{c}`' for c in close)}? "
                f"(every field of {path}: /docs)")
    return f"unknown field `{key}`; the fields of {path} are {sorted(names)}"


def _validate(fields: type[M], values: dict[str, Any]) -> M:
    """The endpoint's own fields; pydantic's errors as a 422 listing them."""
    try:
        return fields.model_validate(values)
    except ValidationError as exc:
        errors = [{"loc": [str(p) for p in e["loc"]], "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
        summary = "; ".join(f"{'.'.join(e['loc'])}: {e['msg']}" for e in errors[:5])
        raise Problem(422, INVALID_INPUT, summary, extra={"errors": errors}) from None


def check_image(name: str, data: bytes, settings: Settings) -> None:
    """Format from the magic bytes and pixels from the header, before any decoding
    (:func:`reglib.io.check_image_header`). Its ``ImageTooLarge`` and ``UnsupportedFormat`` go up as
    they are; any other ``InputError`` means the header cannot be read: :class:`UndecodableImage`, as a
    worker that cannot decode an image says. The problem table answers each (413, 415, 400)."""
    try:
        check_image_header(data, max_pixels=settings.max_pixels, allowed=tuple(settings.allowed_formats), name=name)
    except (ImageTooLarge, UnsupportedFormat):
        raise
    except InputError as exc:
        raise UndecodableImage(str(exc)) from None
