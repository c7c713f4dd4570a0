"""Point-set registration without known correspondences: shape context + L2E, CPD, and the rigid
family for 3-D scans (robust ICP, HMRF ICP, colour GMM, density-adaptive, variational Bayes)."""
from .bayes import BayesOptions
from .color_gmm import ColorGMMOptions
from .cpd import CPDOptions
from .density_adaptive import DensityAdaptiveOptions
from .hmrf import HMRFOptions
from .icp import ICPOptions
from .register import METHODS, RIGID_METHODS, options_class, register_points
from .result import Registration
from .rigid import RigidFit, rigid_warp
from .sc_l2e import RegistrationOptions

__all__ = ["BayesOptions", "ColorGMMOptions", "CPDOptions", "DensityAdaptiveOptions", "HMRFOptions", "ICPOptions",
           "METHODS", "RIGID_METHODS", "Registration", "RegistrationOptions", "RigidFit",
           "options_class", "register_points", "rigid_warp"]
