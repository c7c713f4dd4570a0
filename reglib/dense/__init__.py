"""The dense stage: fields and warps of a transform over a pixel grid, and the guided dense refinement.

- :mod:`reglib.dense.flow`: a transform on every pixel (``dense_flow``), image warps
  (``warp_image``), the fold check (``fold_fraction``) and the resampling the search uses.
- :mod:`reglib.dense.correlation`: the correlation search, patches of a on a grid found in b
  near an estimate (``search_grid``; ``guided_matches``, its public form).
- :mod:`reglib.dense.confidence`: how well the images support a transform (``check_support``,
  ``supported``), per pixel (``confidence_map``) and summarized (``confidence_summary``).
- :mod:`reglib.dense.options`: ``DenseOptions``, what the stage runs with.
- :mod:`reglib.dense.detail`: a narrow-kernel lattice fit over a smooth fit (``detailed``), for
  strongly bent fields (the stage's ``detail`` option).
- :mod:`reglib.dense.refine`: the stage itself, coarse to fine (``refine_dense``), and its guard.
- :mod:`reglib.dense.align`: rigid alignment by normalized mutual information.

Coordinates are (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0); a
transform maps image a into image b. The functions documented "trusted input" do not validate.
"""
from .align import RigidAlignment, align_rigid
from .confidence import check_support, confidence_map, confidence_summary, local_similarity, supported
from .correlation import (
    GridSearch,
    SearchSpec,
    Thresholds,
    area_resized,
    guided_matches,
    multi_channel_maps,
    multi_channel_ncc,
    on_lattice,
    search_grid,
    texture_at,
    texture_map,
)
from .detail import detailed
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
from .options import DENSE_L2E, DENSE_VFC, DenseOptions
from .refine import (
    DENSE_OUTCOMES,
    EVIDENCE_Z,
    DenseFit,
    DenseResult,
    Evidence,
    WorkingFrames,
    barely_moved,
    evidence_over_no_motion,
    evidence_z,
    guard,
    keep_first,
    refine_dense,
    working_frames,
)

__all__ = [
    "DENSE_L2E",
    "DENSE_OUTCOMES",
    "EVIDENCE_Z",
    "DENSE_VFC",
    "DenseFit",
    "DenseOptions",
    "DenseResult",
    "Evidence",
    "GridSearch",
    "RigidAlignment",
    "SearchSpec",
    "Thresholds",
    "WorkingFrames",
    "align_rigid",
    "area_resized",
    "as_shape",
    "as_transform",
    "barely_moved",
    "check_support",
    "confidence_map",
    "confidence_summary",
    "dense_flow",
    "detailed",
    "evidence_over_no_motion",
    "evidence_z",
    "fold_fraction",
    "guard",
    "guided_matches",
    "keep_first",
    "local_similarity",
    "multi_channel_maps",
    "multi_channel_ncc",
    "on_lattice",
    "refine_dense",
    "remap_image",
    "remap_planes",
    "sample_positions",
    "search_grid",
    "supported",
    "texture_at",
    "texture_map",
    "warp_image",
    "working_frames",
]
