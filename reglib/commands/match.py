"""``reglib match A B --out DIR``: match two images and write the results and pictures into DIR."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..matching import match_request_specs
from ._flags import add_option_flags, given_options

NAME = "match"
HELP = "match two images: inliers, the transform a -> b, dense flow, the warped image and pictures"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("image_a", type=Path, help="image a (PNG, JPEG, TIFF, BMP or WebP)")
    parser.add_argument("image_b", type=Path, help="image b; the transform maps a into b")
    parser.add_argument("--out", type=Path, required=True,
                        help="folder for match.json, transform.json, flow.flo, warped.png, matches.png, overlay.png")
    parser.add_argument("--mask-a", type=Path, help="region of interest of a (image, nonzero = use)")
    parser.add_argument("--mask-b", type=Path, help="region of interest of b")
    parser.add_argument("--no-pictures", action="store_true", help="skip matches.png and overlay.png")
    # every field of the match request (features, method, seed, MatchOptions), derived from the library
    add_option_flags(parser, match_request_specs(), aliases={"filter": ["--filter-options"]})


def run(args: argparse.Namespace) -> int:
    from ..io import read_image
    from ..matching import MatchRequest
    from ..outputs import save_match

    request = MatchRequest.from_fields(given_options(args), what="reglib match")
    limit = request.options.max_pixels
    a = read_image(args.image_a, max_pixels=limit, name="image_a")
    b = read_image(args.image_b, max_pixels=limit, name="image_b")
    mask_a = None if args.mask_a is None else read_image(args.mask_a, name="mask_a")
    mask_b = None if args.mask_b is None else read_image(args.mask_b, name="mask_b")
    if mask_a is not None and mask_a.ndim == 3:
        mask_a = mask_a.max(axis=2)
    if mask_b is not None and mask_b.ndim == 3:
        mask_b = mask_b.max(axis=2)
    match = request.run(a, b, mask_a=mask_a, mask_b=mask_b)
    save_match(match, args.out, image_a=a, image_b=b, pictures=not args.no_pictures)
    status = "converged" if match.converged else f"not converged ({match.reason or 'iteration cap'})"
    print(f"{match.n_inliers}/{match.n_matches} inliers, {len(match.keypoints_a)}/{len(match.keypoints_b)} keypoints, "
          f"{status}, folds {100 * match.fold_fraction:.2f} %, {match.timings_ms['total']:.0f} ms -> {args.out}")
    return 0
