"""The web page (``/``) and the example pair it offers (``/examples``): the images of ``reglib/examples/``.

The page's scripts and styles are files under ``/static`` (no inline script), so that a strict
Content-Security-Policy can be set on it. The examples are served from the library's own folder, the
pair the README's quick start uses, so the page and the README show the same images.
"""
from __future__ import annotations

from importlib import resources

from fastapi import APIRouter
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse

from reglib.examples import example_pair

from ..problems import NOT_FOUND, Problem

router = APIRouter(include_in_schema=False)

_MEDIA = {".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".png": "image/png"}


@router.get("/")
async def page() -> HTMLResponse:
    return HTMLResponse((resources.files("service") / "static" / "index.html").read_text(encoding="utf-8"))


@router.get("/examples")
async def examples() -> JSONResponse:
    """``{"image_a": url, "image_b": url}`` of the bundled example pair."""
    a, b = example_pair()
    return JSONResponse({"image_a": f"/examples/{a.name}", "image_b": f"/examples/{b.name}"})


@router.get("/examples/{name}")
async def example_image(name: str) -> FileResponse:
    """One image of the example pair, by its file name (nothing else of the folder is served)."""
    paths = {path.name: path for path in example_pair()}
    if name not in paths:
        raise Problem(404, NOT_FOUND, f"no example image {name!r}; the examples are {sorted(paths)}")
    path = paths[name]
    return FileResponse(path, media_type=_MEDIA.get(path.suffix.lower(), "application/octet-stream"))
