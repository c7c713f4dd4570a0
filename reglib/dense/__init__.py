"""The dense stage: displacement fields and warps of a transform over a pixel grid.

:mod:`reglib.dense.flow` evaluates a transform on every pixel (``dense_flow``), warps images
(``warp_image``) and measures folds (``fold_fraction``).
"""
from .flow import (
    as_shape,
    as_transform,
    dense_flow,
    fold_fraction,
    remap_image,
    remap_planes,
    sample_positions,
    warp_image,
)

__all__ = ["as_shape", "as_transform", "dense_flow", "fold_fraction", "remap_image", "remap_planes",
           "sample_positions", "warp_image"]
