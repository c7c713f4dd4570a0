"""reglib: robust feature correspondence and non-rigid registration.

The public API is re-exported here; see each function's docstring.
"""
from . import io, outputs, visualize
from ._evaluate import Evaluation, evaluate
from ._transforms import KernelWarp
from ._verdict import REASONS, Reason
from .dense import WarpedFile, dense_flow, fold_fraction, warp_image, warp_image_file
from .errors import EstimationError, InputError, ReglibError
from .matching import ImageMatch, MatchOptions, MatchRequest, match_images
from .registration import (
    BayesOptions,
    ColorGMMOptions,
    CPDOptions,
    DensityAdaptiveOptions,
    HMRFOptions,
    ICPOptions,
    Registration,
    RegistrationOptions,
    register_points,
)
from .robust import FilterResult, L2EOptions, VFCOptions, filter_matches

__version__ = "0.1.0"

__all__ = [
    "BayesOptions",
    "CPDOptions",
    "ColorGMMOptions",
    "DensityAdaptiveOptions",
    "EstimationError",
    "Evaluation",
    "FilterResult",
    "HMRFOptions",
    "ICPOptions",
    "ImageMatch",
    "InputError",
    "KernelWarp",
    "L2EOptions",
    "MatchOptions",
    "MatchRequest",
    "REASONS",
    "Reason",
    "Registration",
    "RegistrationOptions",
    "ReglibError",
    "VFCOptions",
    "WarpedFile",
    "dense_flow",
    "evaluate",
    "filter_matches",
    "fold_fraction",
    "io",
    "match_images",
    "outputs",
    "register_points",
    "visualize",
    "warp_image",
    "warp_image_file",
]
