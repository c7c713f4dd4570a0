"""The dense stage: fields and warps of a transform over a pixel grid, and the guided dense refinement.

- :mod:`reglib.dense._flow`: a transform on every pixel (``dense_flow``), image warps
  (``warp_image``), the fold check (``fold_fraction``) and the resampling the search uses.
- :mod:`reglib.dense._tiled_warp`: the warp of an image larger than memory, tile by tile from its
  file to a tiled TIFF (``warp_image_file``); :mod:`reglib.dense._banded_flow`: the flow of such a
  frame written band by band (``write_flow_banded``).
- :mod:`reglib.dense._fields`: the images as float32 (H, W, C) fields and their resized copies
  (``area_resized``).
- :mod:`reglib.dense._texture`: how textured a's patches are (``texture_map``, ``texture_at``).
- :mod:`reglib.dense._ncc`: the correlation of multi-channel fields (``multi_channel_maps``,
  ``multi_channel_ncc``).
- :mod:`reglib.dense._correlation`: the correlation search, patches of a on a grid found in b
  near an estimate (``search_grid``).
- :mod:`reglib.dense._guided`: the matches of such a search (``guided_matches``, its public form).
- :mod:`reglib.dense._confidence`: how well the images support a transform (``check_support``,
  ``supported``), per pixel (``confidence_map``) and summarized (``confidence_summary``); where a wider
  search finds a's patches away from it (``found_away``).
- :mod:`reglib.dense._evidence`: the images' local similarity at a transform (``local_similarity``)
  and the sign test between two transforms (``evidence_z``, ``evidence_over_no_motion``,
  ``rate_over_no_motion``).
- :mod:`reglib.dense._options`: ``DenseOptions``, what the stage runs with.
- :mod:`reglib.dense._detail`: a narrow-kernel lattice fit over a smooth fit (``detailed``), for
  strongly bent fields (the stage's ``detail`` option).
- :mod:`reglib.dense._result`: what the stage returns (``DenseResult``, ``DENSE_OUTCOMES``) and the
  records its rounds hand to its guard (``WorkingFrames``, ``DenseFit``, ``Evidence``).
- :mod:`reglib.dense._guarding`: the guard, the dense estimate weighed against the first one
  (``guard``, ``keep_first``).
- :mod:`reglib.dense._refine`: the stage itself, coarse to fine (``refine_dense``).
- :mod:`reglib.dense._align`: rigid alignment by normalized mutual information.
- :mod:`reglib.dense._residual_start`: a start for the stage that needs no putatives, the motion a
  first fit left found by optical flow (``residual_start``).

The package exports what the rest of the library and its users call; the modules' other names
(the search, the guard, the evidence's sign test, ...) are the stage's implementation, imported by
their tests from the module that holds them.

Coordinates are (x, y) pixels, x the column, the centre of the top-left pixel at (0, 0); a
transform maps image a into image b. The functions documented "trusted input" do not validate.
"""
from ._align import RigidAlignment, align_rigid
from ._banded_flow import BANDED_FLOW_SUFFIXES, write_flow_banded
from ._confidence import MAX_FOUND_AWAY, confidence_map, confidence_summary, found_away
from ._detail import detailed
from ._evidence import EVIDENCE_Z, OverNoMotion, evidence_over_no_motion, rate_over_no_motion
from ._flow import as_shape, dense_flow, fold_fraction, remap_image, warp_image
from ._guided import guided_matches
from ._options import DENSE_L2E, DENSE_VFC, DenseOptions
from ._refine import refine_dense
from ._residual_start import residual_start
from ._result import DENSE_OUTCOMES, DenseResult
from ._texture import texture_map
from ._tiled_warp import WarpedFile, warp_image_file

__all__ = [
    "BANDED_FLOW_SUFFIXES",
    "DENSE_L2E",
    "DENSE_OUTCOMES",
    "DENSE_VFC",
    "DenseOptions",
    "DenseResult",
    "WarpedFile",
    "EVIDENCE_Z",
    "MAX_FOUND_AWAY",
    "OverNoMotion",
    "RigidAlignment",
    "align_rigid",
    "as_shape",
    "confidence_map",
    "confidence_summary",
    "dense_flow",
    "detailed",
    "evidence_over_no_motion",
    "rate_over_no_motion",
    "fold_fraction",
    "found_away",
    "guided_matches",
    "refine_dense",
    "remap_image",
    "residual_start",
    "texture_map",
    "warp_image",
    "warp_image_file",
    "write_flow_banded",
]
