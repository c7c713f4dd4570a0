"""reglib: robust feature correspondence and non-rigid registration.

The public API is re-exported here; see each function's docstring.
"""
from . import io, outputs, visualize
from .dense import dense_flow, fold_fraction, warp_image
from .errors import EstimationError, InputError, ReglibError
from .pipeline import ImageMatch, MatchOptions, match_images
from .registration import CPDOptions, Registration, RegistrationOptions, register_points
from .robust import FilterResult, L2EOptions, VFCOptions, filter_matches
from .transforms import KernelWarp

__version__ = "0.1.0"

__all__ = [
    "CPDOptions",
    "Registration",
    "RegistrationOptions",
    "register_points",
    "EstimationError",
    "ImageMatch",
    "MatchOptions",
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
    "outputs",
    "visualize",
    "warp_image",
]
