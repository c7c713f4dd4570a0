"""Point-set registration without known correspondences: shape context + L2E, and CPD."""
from .cpd import CPDOptions
from .register import METHODS, Registration, RegistrationOptions, register_points
from .shape_context_3d import shape_context_3d

__all__ = ["CPDOptions", "METHODS", "Registration", "RegistrationOptions", "register_points", "shape_context_3d"]
