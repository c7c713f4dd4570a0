"""``reglib match A B --out DIR``: match two images and write the results and pictures into DIR."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from .._large_outputs import is_large
from ..io import is_large_tiff
from ..matching import match_request_specs
from ..outputs import FLOW_FORMATS, writes_motion
from ._flags import add_option_flags, given_options, out_folder

if TYPE_CHECKING:  # pragma: no cover
    from ..matching import ImageMatch, MatchRequest

NAME = "match"
HELP = "match two images: inliers, the transform a -> b, dense flow, the warped image and pictures"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("image_a", type=Path, help="image a (PNG, JPEG, TIFF, BMP or WebP)")
    parser.add_argument("image_b", type=Path, help="image b; the transform maps a into b")
    parser.add_argument("--out", type=Path, required=True,
                        help="folder (created; its parent must exist) for match.json, transform.json, flow.flo "
                             "(or flow.mha, ... with --flow-format), confidence.png, warped.png, and with pictures "
                             "matches.png, overlay.png")
    parser.add_argument("--flow-format", choices=FLOW_FORMATS, default="flo",
                        help=f"file of the dense flow a -> b, flow.<format>: {', '.join(FLOW_FORMATS)} (default flo, "
                             "Middlebury; npy, numpy's (H, W, 2) float32; mha, nrrd, nii, nii.gz: an ITK "
                             "displacement field for medical tools, spacing 1, origin 0, vectors in pixels; see "
                             "reglib.io.write_flow)")
    parser.add_argument("--mask-a", type=Path, help="region of interest of a (image, nonzero = use)")
    parser.add_argument("--mask-b", type=Path, help="region of interest of b")
    parser.add_argument("--no-pictures", action="store_true", help="skip matches.png and overlay.png")
    # every field of the match request (features, method, seed, MatchOptions), derived from the library
    add_option_flags(parser, match_request_specs(), aliases={"filter": ["--filter-options"]})


def run(args: argparse.Namespace) -> int:
    from ..io import read_image
    from ..matching import MatchRequest
    from ..outputs import save_match

    out = out_folder(args.out)
    request = MatchRequest.from_fields(given_options(args), what="reglib match")
    limit = request.options.max_pixels
    if is_large_tiff(args.image_a, limit) or is_large_tiff(args.image_b, limit):
        return _run_large(args, request, out)
    a = read_image(args.image_a, max_pixels=limit, name="image_a")
    b = read_image(args.image_b, max_pixels=limit, name="image_b")
    mask_a = None if args.mask_a is None else read_image(args.mask_a, name="mask_a")
    mask_b = None if args.mask_b is None else read_image(args.mask_b, name="mask_b")
    if mask_a is not None and mask_a.ndim == 3:
        mask_a = mask_a.max(axis=2)
    if mask_b is not None and mask_b.ndim == 3:
        mask_b = mask_b.max(axis=2)
    match = request.run(a, b, mask_a=mask_a, mask_b=mask_b)
    save_match(match, out, image_a=a, image_b=b, pictures=not args.no_pictures, flow_format=args.flow_format)
    print(summary(match, request, out))
    return 0


def _run_large(args: argparse.Namespace, request: MatchRequest, out: Path) -> int:
    """A pair of TIFFs over the pixel limit: matched at a working size (paths handed to the library), no flow or warp
    written (the note says how to get them), the pictures at a reduced size."""
    from ..outputs import save_match

    match = request.run(args.image_a, args.image_b, mask_a=args.mask_a, mask_b=args.mask_b)
    save_match(match, out, image_a=args.image_a, image_b=args.image_b, pictures=not args.no_pictures, flow=False,
               warped=False, max_pixels=request.options.max_pixels)
    h, w = match.shape_a
    print(summary(match, request, out))
    print(f"large pair ({w}x{h} pixels of a): matched at a working size of at most {request.options.max_side} px "
          "and mapped back to full resolution; no flow (8 bytes a pixel) and no warped image written, pictures "
          f"drawn at a reduced size; `reglib apply {out / 'transform.json'} {args.image_b} --out warped.tif "
          f"--shape-a {h} {w}` writes the warp as a tiled TIFF")
    return 0


def summary(match: ImageMatch, request: MatchRequest, out: Path) -> str:
    """The line ``reglib match`` prints: inliers, convergence (with its reason), the confidence, whether the
    dense stage's result was kept, folds and time; then a hint when SIFT did not converge."""
    status = "converged" if match.converged else f"not converged ({match.reason})"
    conf = match.confidence_summary
    confidence = "no confidence map" if conf is None else (
        f"confidence mean {conf['mean']:.2f} ({100 * conf['supported_share']:.0f} % supported)")
    if not request.options.dense:
        dense = "dense off"
    elif match.reason is not None:
        dense = "dense skipped (no estimate to refine)"
    elif match.n_dense > 0:
        dense = f"dense kept (+{match.n_dense} matches)"
    else:
        dense = "dense not kept (the sparse estimate stands)"
    line = (f"{match.n_inliers}/{match.n_matches} inliers, {len(match.keypoints_a)}/{len(match.keypoints_b)} "
            f"keypoints ({match.features}), {status}, {confidence}, {dense}, folds {100 * match.fold_fraction:.2f} %, "
            f"{match.timings_ms['total']:.0f} ms -> {out}")
    if match.converged and conf is not None and float(conf["mean"]) < 0.1:
        line += (f"\nwarning: the images hardly support this answer (confidence mean {conf['mean']:.2f}); "
                 "look at overlay.png before trusting it")
    if not writes_motion(match) and not is_large(match, request.options.max_pixels):
        line += ("\nnot converged: no flow, warped image or overlay written (transform.json, matches.png and "
                 "match.json are; `reglib apply` warps with the transform on purpose)")
    if not match.converged and request.features == "sift":
        line += ("\nhint: SIFT found too little to trust; try --features auto (SIFT, then the multimodal path "
                 "for images from different sensors or contrasts)")
    return line
