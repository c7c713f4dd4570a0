"""``reglib apply TRANSFORM.json INPUT --out FILE``: apply a saved transform to an image or to points."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "apply"
HELP = ("apply a saved transform (a -> b): warp an image of b into a's frame (--shape-a H W), "
        "or map points of a (text x y rows, .npy, .ply or .pcd) into b")

_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("transform", type=Path, help="transform.json (or a match.json holding one)")
    parser.add_argument("input", type=Path,
                        help="an image of b (e.g. a segmentation), or points of a (.txt/.csv/.npy/.ply/.pcd)")
    parser.add_argument("--out", type=Path, required=True, help="output image (.png, .tif, ...) or points (.txt/.npy)")
    parser.add_argument("--shape-a", type=int, nargs=2, metavar=("H", "W"),
                        help="size of a's frame for images (default: match.json's shape_a, else the input's size)")
    parser.add_argument("--interpolation", default="linear", choices=["linear", "nearest"],
                        help="'nearest' keeps label values exactly")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..dense import warp_image
    from ..errors import InputError
    from ..io import encode_png, read_image, read_points, write_bytes_atomic
    from ..transforms import KernelWarp

    if not args.transform.is_file():
        raise InputError(f"no such transform file: {args.transform}")
    try:
        body = json.loads(args.transform.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{args.transform.name}: not JSON: {exc}") from None
    shape_a = None
    if isinstance(body, dict) and "transform" in body and isinstance(body["transform"], dict):
        shape_a = body.get("shape_a")
        body = body["transform"]
    transform = KernelWarp.from_dict(body)
    if args.input.suffix.lower() in _IMAGE_SUFFIXES:
        if transform.dim != 2:
            raise InputError("images need a 2-D transform")
        image = read_image(args.input, name="input")
        shape = tuple(args.shape_a) if args.shape_a else (tuple(shape_a) if shape_a else image.shape[:2])
        warped, valid = warp_image(image, transform, shape, interpolation=args.interpolation)
        if args.out.suffix.lower() != ".png":
            raise InputError(f"--out for an image must be a .png file, got {args.out.name}")
        if warped.dtype not in (np.uint8, np.uint16):
            from ..visualize import to_rgb_uint8

            warped = to_rgb_uint8(warped, "input")
        write_bytes_atomic(args.out, encode_png(warped))
        print(f"warped {image.shape[1]}x{image.shape[0]} -> {shape[1]}x{shape[0]} "
              f"({100 * valid.mean():.1f} % inside) -> {args.out}")
        return 0
    points = read_points(args.input)  # text, .npy, .ply or .pcd; InputError naming the file's problem
    mapped = transform(points)
    if args.out.suffix == ".npy":
        import io as _io

        buf = _io.BytesIO()
        np.save(buf, mapped, allow_pickle=False)
        write_bytes_atomic(args.out, buf.getvalue())
    else:
        text = "\n".join(" ".join(repr(float(v)) for v in row) for row in mapped) + "\n"
        write_bytes_atomic(args.out, text.encode())
    print(f"mapped {len(mapped)} points -> {args.out}")
    return 0
