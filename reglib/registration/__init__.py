"""Point-set registration without known correspondences: shape context + L2E, CPD, and the rigid
family for 3-D scans (robust ICP, HMRF ICP, color GMM, density-adaptive, variational Bayes).

:func:`register_points` runs every method of the table :data:`METHODS` (one :class:`Method`
record per method: its options class, function, the map it fits and the extras it takes).
"""
from .._verdict import REGISTRATION_REASONS
from .bayes import BayesOptions
from .color_gmm import ColorGMMOptions
from .cpd import CPDOptions
from .density_adaptive import DensityAdaptiveOptions
from .em import EMOptions, SceneEMOptions
from .hmrf import HMRFOptions
from .icp import ICPOptions
from .methods import METHODS, RIGID_METHODS, Method, MethodName, options_class
from .register import register_points
from .result import Registration, WarpFit
from .rigid import RigidFit, rigid_warp
from .sc_options import RegistrationOptions

__all__ = ["BayesOptions", "CPDOptions", "ColorGMMOptions", "DensityAdaptiveOptions", "EMOptions", "HMRFOptions",
           "ICPOptions", "METHODS", "Method", "MethodName", "REGISTRATION_REASONS", "RIGID_METHODS", "Registration",
           "RegistrationOptions",
           "RigidFit", "SceneEMOptions", "WarpFit", "options_class", "register_points", "rigid_warp"]
