"""Image and point-set features and their matching.

One descriptor per module, one matcher they share:

- :mod:`~reglib.features._sift`: SIFT keypoints with RootSIFT descriptors, for photographs.
- :mod:`~reglib.features._rift`: the multimodal features (RIFT-style phase-congruency corners and
  maximum-index-map descriptors, matched under one global rotation hypothesis), for pairs from
  different sensors.
- :mod:`~reglib.features._phase`: the log-Gabor bank and Kovesi's phase congruency under them.
- :mod:`~reglib.features._structure`: dense structure fields (CFOG) and the refinement of
  cross-modal matches by correlating them.
- :mod:`~reglib.features._shape_context`, :mod:`~reglib.features._shape_context_3d`: shape context
  histograms of 2-D and 3-D point sets, their chi^2 cost and one-to-one assignment.
- :mod:`~reglib.features._fpfh`: FPFH descriptors of 3-D point sets (Rusu et al. 2009) on
  voxel-downsampled scans with oriented PCA normals, and their mutual matches.
- :mod:`~reglib.features._edges`: edge points of an image, the point set of a contour.
- :mod:`~reglib.features._matching`: nearest-neighbour matching with Lowe's ratio test and the
  mutual check (Euclidean for SIFT, cosine for the unit-norm multimodal descriptors).
- :mod:`~reglib.features._peaks`: sub-pixel peaks by a parabola through three samples.
- :mod:`~reglib.features._normalize`: image preparation (intensity normalisation, grey copies, masks).
- :mod:`~reglib.features._keypoints`: :class:`Features`, what the image detectors return.

Coordinates everywhere: (x, y), x the column; image pixels have their centre at integers, the
top-left one at (0, 0).
"""
from ._edges import edge_points
from ._fpfh import FPFH_BINS, fpfh, match_features, oriented_normals, voxel_downsample
from ._keypoints import Features
from ._matching import match_descriptors, match_unit_descriptors, select_matches
from ._normalize import NormalizedImage, check_mask, feature_bands, intensity_range, normalize_intensity, to_gray_uint8
from ._peaks import parabola_vertex, subpixel_peaks
from ._phase import LogGaborBank, PhaseCongruency, log_gabor_bank, phase_congruency
from ._rift import N_ROTATIONS, detect_multimodal, match_multimodal
from ._shape_context import chi2_cost, match_shape_contexts, rotate_bins, shape_context
from ._shape_context_3d import shape_context_3d
from ._sift import detect_sift, resize_factor, root_sift
from ._structure import refine_matches, structure_image

__all__ = [
    "FPFH_BINS",
    "Features",
    "LogGaborBank",
    "N_ROTATIONS",
    "NormalizedImage",
    "PhaseCongruency",
    "check_mask",
    "chi2_cost",
    "detect_multimodal",
    "detect_sift",
    "edge_points",
    "feature_bands",
    "fpfh",
    "intensity_range",
    "log_gabor_bank",
    "match_descriptors",
    "match_features",
    "match_multimodal",
    "match_shape_contexts",
    "match_unit_descriptors",
    "normalize_intensity",
    "oriented_normals",
    "parabola_vertex",
    "phase_congruency",
    "refine_matches",
    "resize_factor",
    "root_sift",
    "rotate_bins",
    "select_matches",
    "shape_context",
    "shape_context_3d",
    "structure_image",
    "subpixel_peaks",
    "to_gray_uint8",
    "voxel_downsample",
]
