"""``reglib apply TRANSFORM.json INPUT --out FILE``: apply a saved transform to an image or to points,
or write its dense flow (``--out flow.mha`` for medical tools)."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from ..outputs import FLOW_FORMATS
from ._flags import out_file, read_transform_file

if TYPE_CHECKING:  # pragma: no cover
    from .. import KernelWarp

NAME = "apply"
HELP = ("apply a saved transform (a -> b): warp an image of b into a's frame (--shape-a H W), "
        "map points of a (text x y rows, .npy, .ply or .pcd) into b, or write the dense flow a -> b "
        f"(--out flow.<format>, format one of {', '.join(FLOW_FORMATS)})")
_FLOW_NAMES = ", ".join(f".{fmt}" for fmt in FLOW_FORMATS)

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp",
                   ".nii", ".nii.gz", ".mha", ".mhd", ".nrrd")


def _is_image(path: Path | None) -> bool:
    return path is not None and path.name.lower().endswith(_IMAGE_SUFFIXES)


def _is_flow_file(path: Path) -> bool:
    """Whether ``path`` names a flow file (``.npy`` too: it is the flow unless the INPUT is points of a)."""
    name = path.name.lower()
    return any(name.endswith(f".{fmt}") for fmt in FLOW_FORMATS)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("transform", type=Path, help="transform.json (or a match.json holding one)")
    parser.add_argument("input", type=Path, nargs="?",
                        help="an image of b (e.g. a segmentation; any bands and dtype; also a 2-D .nii/.nii.gz/"
                             ".mha/.mhd/.nrrd), or points of a (.txt/.csv/.npy/.ply/.pcd); "
                             "for a flow --out, optional (an image of a gives a's size)")
    parser.add_argument("--out", type=Path, required=True,
                        help="warped image (.png, .tif, .bmp), .tif keeping every band and the dtype; mapped points "
                             "(.txt/.npy/.ply/.pcd, with a point file as INPUT), or the dense flow a -> b: "
                             f"{_FLOW_NAMES} (.mha, .nrrd, .nii, .nii.gz: an ITK displacement field, spacing 1, "
                             "origin 0, vectors in pixels; .npy is the flow unless INPUT is points); its folder "
                             "must exist")
    parser.add_argument("--shape-a", type=int, nargs=2, metavar=("H", "W"),
                        help="size of a's frame for images and flows (default: match.json's shape_a, else the "
                             "input's size)")
    parser.add_argument("--interpolation", default="linear", choices=["linear", "nearest"],
                        help="'nearest' keeps label values exactly")
    parser.add_argument("--pyramid", action="store_true",
                        help="write the warp as a tiled .tif with halved levels (a pyramid tifffile, OpenSlide and "
                             "QuPath read); a warp of a TIFF over the pixel limit, or of a frame over it, is "
                             "written as a tiled .tif tile by tile in any case")


def run(args: argparse.Namespace) -> int:
    from .. import KernelWarp
    from ..errors import InputError
    from ..io import IMAGE_OUT_SUFFIXES, read_image

    out = out_file(args.out)
    body, shapes = read_transform_file(args.transform)
    shape_a = shapes["shape_a"]
    transform = KernelWarp.from_dict(body)
    is_image = _is_image(args.input)
    if _is_flow_file(out) and (is_image or args.input is None):
        return _write_flow(args, transform, shape_a, out)
    if args.input is None:
        raise InputError(f"give an INPUT (an image of b or points of a), or --out a flow file ({_FLOW_NAMES})")
    if not is_image:
        return _map_points(args, transform, out)
    if transform.dim != 2:
        raise InputError("images need a 2-D transform")
    if out.suffix.lower() not in IMAGE_OUT_SUFFIXES:
        raise InputError(f"--out {out.name}: a warped image is written as {', '.join(IMAGE_OUT_SUFFIXES)}, "
                         f"a flow as {_FLOW_NAMES}")
    if args.pyramid or _is_big(args.input, args.shape_a or shape_a):
        return _write_tiled(args, transform, shape_a, out)
    image = read_image(args.input, name="input")
    shape = tuple(args.shape_a) if args.shape_a else (tuple(shape_a) if shape_a else image.shape[:2])
    _write_warped(image, transform, shape, args.interpolation, out)
    return 0


def _is_big(path: Path, shape: Any) -> bool:
    """Whether a warp is made tile by tile: the input a TIFF over the pixel limit, or a's frame over it."""
    from ..io import DEFAULT_MAX_PIXELS, is_tiff_file, tiff_shape

    if shape and int(shape[0]) * int(shape[1]) > DEFAULT_MAX_PIXELS:
        return True
    if not is_tiff_file(path):
        return False
    h, w, _ = tiff_shape(path, "input")
    return h * w > DEFAULT_MAX_PIXELS


def _write_tiled(args: argparse.Namespace, transform: KernelWarp, shape_a: Any, out: Path) -> int:
    """b warped tile by tile from its file into a tiled TIFF (:func:`reglib.warp_image_file`)."""
    from ..dense import warp_image_file
    from ..errors import InputError
    if out.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"--out {out.name}: a warp this large (or with --pyramid) is written as a tiled .tif")
    if args.shape_a or shape_a:
        shape = tuple(args.shape_a or shape_a)
    else:
        shape = _image_shape(args.input)
    done = warp_image_file(args.input, transform, shape, out, interpolation=args.interpolation, pyramid=args.pyramid)
    levels = f", {done.levels} pyramid levels" if done.levels > 1 else ""
    print(f"warped -> {shape[1]}x{shape[0]} tiled TIFF ({done.bands} band(s) of {done.dtype}{levels}, "
          f"{100 * done.inside:.1f} % inside) -> {out}")
    return 0


def _image_shape(path: Path) -> tuple[int, int]:
    """(H, W) of an image file: a TIFF's from its header, another format's read whole."""
    from ..io import is_tiff_file, read_image, tiff_shape

    if is_tiff_file(path):
        return tiff_shape(path, "input")[:2]
    image = read_image(path, name="input")
    return int(image.shape[0]), int(image.shape[1])


def _write_warped(image: Any, transform: KernelWarp, shape: tuple[int, ...],
                  interpolation: Literal["linear", "nearest"], out: Path) -> None:
    """b warped into a's frame, written by ``out``'s suffix: TIFF keeps every band and the dtype; PNG and BMP
    hold 8 or 16 bits (another dtype is converted for display)."""
    import numpy as np

    from ..dense import warp_image
    from ..io import encode_image, write_bytes_atomic

    warped, valid = warp_image(image, transform, shape, interpolation=interpolation)
    tiff = out.suffix.lower() in (".tif", ".tiff")
    if warped.dtype not in (np.uint8, np.uint16) and not tiff and (warped.ndim == 2 or warped.shape[2] in (3, 4)):
        from ..visualize import to_rgb_uint8

        warped = to_rgb_uint8(warped, "input")
    write_bytes_atomic(out, encode_image(warped, out.suffix))
    print(f"warped {image.shape[1]}x{image.shape[0]} -> {shape[1]}x{shape[0]} "
          f"({100 * valid.mean():.1f} % inside) -> {out}")


def _write_flow(args: argparse.Namespace, transform: KernelWarp, shape_a: Any, out: Path) -> int:
    from ..dense import dense_flow, write_flow_banded
    from ..errors import InputError
    from ..io import DEFAULT_MAX_PIXELS, write_flow

    if transform.dim != 2:
        raise InputError("a flow needs a 2-D transform")
    if args.shape_a:
        shape = tuple(args.shape_a)
    elif shape_a:
        shape = tuple(shape_a)
    elif _is_image(args.input):
        shape = _image_shape(args.input)
    else:
        raise InputError("a flow needs a's size: give --shape-a H W, a match.json (it holds shape_a), "
                         "or an image of a as INPUT")
    if int(shape[0]) * int(shape[1]) > DEFAULT_MAX_PIXELS:  # 8 bytes a pixel: evaluated and written band by band
        write_flow_banded(out, transform, (int(shape[0]), int(shape[1])))
    else:
        write_flow(out, dense_flow(transform, shape))
    print(f"flow a -> b on {shape[1]}x{shape[0]} pixels of a -> {out}")
    return 0


def _map_points(args: argparse.Namespace, transform: KernelWarp, out: Path) -> int:
    import numpy as np

    from ..io import encode_npy, read_points, write_bytes_atomic, write_points

    points = read_points(args.input)  # text, .npy, .ply or .pcd; InputError naming the file's problem
    mapped = transform(points)
    if out.suffix.lower() == ".npy":
        write_bytes_atomic(out, encode_npy(mapped))
    elif out.suffix.lower() in (".ply", ".pcd"):
        write_points(out, mapped)
    else:
        text = "\n".join(" ".join(repr(float(v)) for v in row) for row in np.atleast_2d(mapped)) + "\n"
        write_bytes_atomic(out, text.encode())
    print(f"mapped {len(mapped)} points -> {out}")
    return 0
