"""reglib: robust feature correspondence and non-rigid registration.

The public API is re-exported here; see each function's docstring.
"""
from . import io, outputs, visualize
from .dense import dense_flow, fold_fraction, warp_image
from .errors import EstimationError, InputError, ReglibError
from .image_match import ImageMatch
from .match_options import MatchOptions
from .pipeline import match_images
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
from .request import MatchRequest
from .robust import FilterResult, L2EOptions, VFCOptions, filter_matches
from .transforms import KernelWarp
from .worker import prepare_worker_process

__version__ = "0.1.0"

__all__ = [
    "BayesOptions",
    "ColorGMMOptions",
    "CPDOptions",
    "DensityAdaptiveOptions",
    "HMRFOptions",
    "ICPOptions",
    "Registration",
    "RegistrationOptions",
    "register_points",
    "EstimationError",
    "ImageMatch",
    "MatchOptions",
    "MatchRequest",
    "FilterResult",
    "InputError",
    "KernelWarp",
    "L2EOptions",
    "ReglibError",
    "VFCOptions",
    "dense_flow",
    "filter_matches",
    "fold_fraction",
    "io",
    "match_images",
    "prepare_worker_process",
    "outputs",
    "visualize",
    "warp_image",
]
