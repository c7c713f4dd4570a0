"""``reglib match A B --out DIR``: match two images and write the results and pictures into DIR."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

NAME = "match"
HELP = "match two images: inliers, the transform a -> b, dense flow, the warped image and pictures"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("image_a", type=Path, help="image a (PNG, JPEG, TIFF, BMP or WebP)")
    parser.add_argument("image_b", type=Path, help="image b; the transform maps a into b")
    parser.add_argument("--out", type=Path, required=True,
                        help="folder for match.json, transform.json, flow.flo, warped.png, matches.png, overlay.png")
    parser.add_argument("--method", default="l2e", choices=["l2e", "vfc"])
    parser.add_argument("--features", default="sift", choices=["sift", "shape_context"],
                        help="shape_context: for silhouettes and drawings (edge points, no dense step)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ratio", type=float, default=0.8, help="Lowe ratio test (1.0: every nearest neighbour)")
    parser.add_argument("--mutual", action="store_true", help="keep only mutual nearest neighbours")
    parser.add_argument("--max-keypoints", type=int, default=4000)
    parser.add_argument("--no-dense", action="store_true", help="skip the guided dense refinement")
    parser.add_argument("--mask-a", type=Path, help="region of interest of a (image, nonzero = use)")
    parser.add_argument("--mask-b", type=Path, help="region of interest of b")
    parser.add_argument("--filter-options", help="estimator options as JSON, e.g. '{\"beta\": 1.0}'")
    parser.add_argument("--no-pictures", action="store_true", help="skip matches.png and overlay.png")


def run(args: argparse.Namespace) -> int:
    from ..errors import InputError
    from ..io import read_image
    from ..outputs import save_match
    from ..pipeline import match_images

    filter_opts = None
    if args.filter_options:
        try:
            filter_opts = json.loads(args.filter_options)
        except json.JSONDecodeError as exc:
            raise InputError(f"--filter-options is not valid JSON: {exc}") from None
        if not isinstance(filter_opts, dict):
            raise InputError("--filter-options must be a JSON object")
    a = read_image(args.image_a, name="image_a")
    b = read_image(args.image_b, name="image_b")
    mask_a = None if args.mask_a is None else read_image(args.mask_a, name="mask_a")
    mask_b = None if args.mask_b is None else read_image(args.mask_b, name="mask_b")
    if mask_a is not None and mask_a.ndim == 3:
        mask_a = mask_a.max(axis=2)
    if mask_b is not None and mask_b.ndim == 3:
        mask_b = mask_b.max(axis=2)
    options = {"ratio": args.ratio, "mutual": args.mutual, "max_keypoints": args.max_keypoints,
               "dense": not args.no_dense, "filter": filter_opts}
    match = match_images(a, b, features=args.features, method=args.method, options=options, rng=args.seed,
                         mask_a=mask_a, mask_b=mask_b)
    save_match(match, args.out, image_a=a, image_b=b, pictures=not args.no_pictures)
    status = "converged" if match.converged else f"not converged ({match.reason or 'iteration cap'})"
    print(f"{match.n_inliers}/{match.n_matches} inliers, {len(match.keypoints_a)}/{len(match.keypoints_b)} keypoints, "
          f"{status}, folds {100 * match.fold_fraction:.2f} %, {match.timings_ms['total']:.0f} ms -> {args.out}")
    return 0
