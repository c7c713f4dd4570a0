"""The web page (``/``), its icon (``/favicon.ico``), the flow picture's colour wheel (``/flow-legend.png``) and
the example pair it offers (``/examples``): the images of ``reglib/examples/``.

The page's scripts and styles are files under ``/static`` (no inline script), so that a strict
Content-Security-Policy can be set on it. The examples are served from the library's own folder, the
pair the README's quick start uses, so the page and the README show the same images.
"""
from __future__ import annotations

import functools
from importlib import resources

from fastapi import APIRouter
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response

from reglib.examples import example_pair

from ..problems import NOT_FOUND, Problem

router = APIRouter(include_in_schema=False)

_MEDIA = {".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".png": "image/png"}
_LEGEND_RADIUS = 48  # pixels: the wheel is 96 x 96, the size the page shows it at
_DAY = "public, max-age=86400"


@router.get("/")
async def page() -> HTMLResponse:
    return HTMLResponse((resources.files("service") / "static" / "index.html").read_text(encoding="utf-8"))


@router.get("/favicon.ico")
async def favicon() -> Response:
    """The page's icon (an SVG: browsers take it at this path too, and a 404 here fills every log)."""
    svg = (resources.files("service") / "static" / "favicon.svg").read_bytes()
    return Response(svg, media_type="image/svg+xml", headers={"Cache-Control": _DAY})


@functools.cache
def _legend_png() -> bytes:
    import numpy as np

    from reglib.io import encode_png
    from reglib.visualize import flow_to_color

    # a disc whose flow at each pixel is its offset from the centre, coloured by the very function that colours
    # flow.png, so the wheel and the picture cannot disagree; outside the disc white, as no motion is
    side = 2 * _LEGEND_RADIUS
    offsets = np.stack(np.meshgrid(np.arange(side), np.arange(side)), axis=-1) - (side - 1) / 2
    picture = flow_to_color(offsets, max_flow=_LEGEND_RADIUS)
    picture[np.hypot(offsets[..., 0], offsets[..., 1]) > _LEGEND_RADIUS] = 255
    return encode_png(picture)


@router.get("/flow-legend.png")
def flow_legend() -> Response:
    """The colour wheel of the flow picture: a colour's direction from the centre is the direction of motion."""
    return Response(_legend_png(), media_type="image/png", headers={"Cache-Control": _DAY})


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
