"""The dense stage: fields and warps of a transform over a pixel grid, and the guided dense refinement.

- :mod:`reglib.dense.flow`: a transform on every pixel (``dense_flow``), image warps
  (``warp_image``), the fold check (``fold_fraction``) and the resampling the search uses.
- :mod:`reglib.dense.fields`: the images as float32 (H, W, C) fields and their resized copies
  (``area_resized``).
- :mod:`reglib.dense.texture`: how textured a's patches are (``texture_map``, ``texture_at``).
- :mod:`reglib.dense.ncc`: the correlation of multi-channel fields (``multi_channel_maps``,
  ``multi_channel_ncc``).
- :mod:`reglib.dense.correlation`: the correlation search, patches of a on a grid found in b
  near an estimate (``search_grid``).
- :mod:`reglib.dense.guided`: the matches of such a search (``guided_matches``, its public form).
- :mod:`reglib.dense.confidence`: how well the images support a transform (``check_support``,
  ``supported``), per pixel (``confidence_map``) and summarized (``confidence_summary``).
- :mod:`reglib.dense.evidence`: the images' local similarity at a transform (``local_similarity``)
  and the sign test between two transforms (``evidence_z``, ``evidence_over_no_motion``).
- :mod:`reglib.dense.options`: ``DenseOptions``, what the stage runs with.
- :mod:`reglib.dense.detail`: a narrow-kernel lattice fit over a smooth fit (``detailed``), for
  strongly bent fields (the stage's ``detail`` option).
- :mod:`reglib.dense.result`: what the stage returns (``DenseResult``, ``DENSE_OUTCOMES``) and the
  records its rounds hand to its guard (``WorkingFrames``, ``DenseFit``, ``Evidence``).
- :mod:`reglib.dense.guarding`: the guard, the dense estimate weighed against the first one
  (``guard``, ``keep_first``).
- :mod:`reglib.dense.refine`: the stage itself, coarse to fine (``refine_dense``).
- :mod:`reglib.dense.align`: rigid alignment by normalized mutual information.

Coordinates are (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0); a
transform maps image a into image b. The functions documented "trusted input" do not validate.
"""
from .align import RigidAlignment, align_rigid
from .confidence import check_support, confidence_map, confidence_summary, supported
from .correlation import GridSearch, SearchSpec, Thresholds, on_lattice, search_grid
from .detail import detailed
from .evidence import EVIDENCE_Z, evidence_over_no_motion, evidence_z, local_similarity
from .fields import area_resized
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
from .guarding import guard, keep_first
from .guided import guided_matches
from .ncc import multi_channel_maps, multi_channel_ncc
from .options import DENSE_L2E, DENSE_VFC, DenseOptions
from .refine import barely_moved, refine_dense, working_frames
from .result import DENSE_OUTCOMES, DenseFit, DenseResult, Evidence, WorkingFrames
from .texture import texture_at, texture_map

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
