"""reglib: robust feature correspondence and non-rigid registration.

The public API is re-exported here; see each function's docstring.
"""
from .errors import EstimationError, InputError, ReglibError
from .robust import FilterResult, L2EOptions, VFCOptions, filter_matches
from .transforms import KernelWarp

__version__ = "0.1.0"

__all__ = [
    "EstimationError",
    "FilterResult",
    "InputError",
    "KernelWarp",
    "L2EOptions",
    "ReglibError",
    "VFCOptions",
    "filter_matches",
]
