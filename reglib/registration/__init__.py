"""Point-set registration without known correspondences: shape context + L2E, CPD, and the rigid
family for 3-D scans (robust ICP, HMRF ICP, color GMM, density-adaptive, variational Bayes).

:func:`register_points` runs every method of the table :data:`METHODS` (one :class:`Method`
record per method: its options class, function, the map it fits and the extras it takes).
"""
from .._verdict import REGISTRATION_REASONS
from ._bayes import BayesOptions
from ._color_gmm import ColorGMMOptions
from ._cpd import CPDOptions
from ._density_adaptive import DensityAdaptiveOptions
from ._em import EMOptions, SceneEMOptions
from ._hmrf import HMRFOptions
from ._icp import ICPOptions
from ._methods import METHODS, RIGID_METHODS, Method, MethodName, method_spec, methods_taking, options_class
from ._normals import estimate_normals
from ._register import register_points
from ._result import Registration, WarpFit
from ._rigid import RigidFit, rigid_warp
from ._sc_options import RegistrationOptions

__all__ = ["BayesOptions", "CPDOptions", "ColorGMMOptions", "DensityAdaptiveOptions", "EMOptions", "HMRFOptions",
           "ICPOptions", "METHODS", "Method", "MethodName", "REGISTRATION_REASONS", "RIGID_METHODS", "Registration",
           "RegistrationOptions",
           "RigidFit", "SceneEMOptions", "WarpFit", "estimate_normals", "method_spec", "methods_taking",
           "options_class", "register_points", "rigid_warp"]
