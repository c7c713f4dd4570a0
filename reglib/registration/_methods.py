"""The registration methods: one :class:`Method` record each, what :func:`register_points` dispatches on.

Each record names the method's options class and its function (imported here, so that a reader
or a type checker follows the call), what kind of map it fits, the extra inputs it takes and how
few points it can work with. The service's method enum and field descriptions, the CLI's
``--method`` choices and the checks of :func:`reglib.register_points` all read :data:`METHODS`.

Two families, by the frame they work in:

- the non-rigid and CPD methods ("l2e", "cpd", "cpd-rigid", "cpd-affine", "cpd-net") take both sets
  normalized (each centered, RMS radius 1) and return a :class:`~reglib.registration._result.WarpFit`;
- the rigid methods (:data:`RIGID_METHODS`) take the sets in the caller's units, so that their
  rotation stays a rotation, and return a :class:`~reglib.registration._rigid.RigidFit`.
"""
from __future__ import annotations

import types
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from .._validation import as_choice
from ._bayes import BayesOptions, bayes_register
from ._color_gmm import ColorGMMOptions, color_gmm_register
from ._cpd import CPDOptions, cpd_affine_register, cpd_register, cpd_rigid_register
from ._cpd_net import CPDNetOptions, cpd_net_register
from ._density_adaptive import DensityAdaptiveOptions, density_adaptive_register
from ._hmrf import HMRFOptions, icp_hmrf_register
from ._icp import ICPOptions, icp_register
from ._sc_l2e import sc_l2e_register
from ._sc_options import RegistrationOptions

__all__ = ["EXTRAS", "METHODS", "RIGID_METHODS", "Extra", "Method", "MethodName", "Use", "method_spec",
           "methods_taking", "options_class"]

MethodName = Literal["l2e", "cpd", "cpd-rigid", "cpd-affine", "cpd-net", "icp", "icp-hmrf", "color-gmm",
                     "density-adaptive", "bayes"]
"""The names of :data:`METHODS`, in its order (the service's enum)."""

Use = Literal["unused", "optional", "required"]
Side = Literal["model", "target"]
Extra = Literal["model_colors", "target_colors", "model_normals", "target_normals"]
EXTRAS: tuple[Extra, ...] = ("model_colors", "target_colors", "model_normals", "target_normals")
"""The keyword arguments of :func:`reglib.register_points` beside the points: ``<side>_<kind>``."""
Motion = Literal["non-rigid", "affine", "similarity", "rigid"]


@dataclass(frozen=True, slots=True)
class Method:
    """One registration method, as :func:`register_points` runs it.

    Attributes
    ----------
    name : str
        The ``method`` string.
    options : type
        Its frozen options dataclass (``options=`` may also be a dict of its fields).
    fit : callable
        The method. Non-rigid and CPD: ``fit(u, y, options, rng) -> WarpFit`` on normalized
        (N, D) and (M, D) points. Rigid: ``fit(model, target, options, rng, **extras) -> RigidFit``
        in the caller's units, the model an (H, W, 3) grid when ``organized_model`` is "required".
    motion : {"non-rigid", "affine", "similarity", "rigid"}
        The map it fits ("similarity": rotation, translation and one scale).
    min_points : (int, int)
        Fewest points each set must have, in 2-D and in 3-D.
    colors, normals : {"unused", "optional", "required"}
        Whether it takes ``model_colors`` / ``target_colors`` (RGB in [0, 1]) and
        ``model_normals`` / ``target_normals`` (unit normals), one row per point.
    normals_of : tuple of {"model", "target"}
        The sets whose normals it takes, when it takes normals (:meth:`use_of` reads both).
    unused : callable, optional
        ``unused(options, given) -> {argument: why}``: the extras among the ``given`` argument
        names that these options leave unused (e.g. ``target_normals`` with a point-to-point
        residual), each with the condition in words; None when every extra it takes is used.
    organized_model : {"optional", "required"}
        Every method takes an organized (H, W, 3) scan as a set of its valid points; "required":
        the method uses the model's pixel grid and needs one.
    summary : str
        One line: what it does, for help texts.
    """

    name: str
    options: type
    fit: Callable[..., Any]
    motion: Motion
    min_points: tuple[int, int] = (3, 3)
    colors: Use = "unused"
    normals: Use = "unused"
    normals_of: tuple[Side, ...] = ("model", "target")
    unused: Callable[[Any, Collection[str]], Mapping[str, str]] | None = None
    organized_model: Literal["optional", "required"] = "optional"
    summary: str = ""

    @property
    def rigid(self) -> bool:
        """A rigid method: fitted in the caller's units, its point sets not all on one line."""
        return self.motion == "rigid"

    def points_needed(self, dim: int) -> int:
        """Fewest points of each set in dimension ``dim`` (2 or 3)."""
        return self.min_points[dim - 2]

    def use_of(self, argument: str) -> Use:
        """Whether it takes the extra ``argument`` (one of :data:`EXTRAS`, e.g. ``"model_normals"``)."""
        side, kind = argument.split("_")
        if kind == "normals" and side not in self.normals_of:
            return "unused"
        use: Use = getattr(self, kind)
        return use


def _table(*methods: Method) -> Mapping[str, Method]:
    return types.MappingProxyType({m.name: m for m in methods})


METHODS: Mapping[str, Method] = _table(
    Method("l2e", RegistrationOptions, sc_l2e_register, "non-rigid", min_points=(5, 5),
           summary="shape context + L2E, non-rigid (Ma et al. 2015)"),
    Method("cpd", CPDOptions, cpd_register, "non-rigid",
           summary="Coherent Point Drift, non-rigid (Myronenko & Song 2010)"),
    Method("cpd-rigid", CPDOptions, cpd_rigid_register, "similarity", min_points=(2, 2),
           summary="Coherent Point Drift: rotation, scale, translation"),
    Method("cpd-affine", CPDOptions, cpd_affine_register, "affine", min_points=(3, 4),
           summary="Coherent Point Drift: affine"),
    Method("cpd-net", CPDNetOptions, cpd_net_register, "non-rigid",
           summary="CPD-Net: a learned coherent displacement field, one forward pass (2-D; Wang et al. 2019)"),
    Method("icp", ICPOptions, icp_register, "rigid", normals="optional", unused=ICPOptions.unused_extras,
           summary="robust point-to-point / point-to-plane ICP"),
    # the field weighs the model's pixels by their distances alone: no model normals
    Method("icp-hmrf", HMRFOptions, icp_hmrf_register, "rigid", normals="optional", normals_of=("target",),
           unused=HMRFOptions.unused_extras, organized_model="required",
           summary="ICP with a hidden Markov random field over an organized scan's pixel grid"),
    Method("color-gmm", ColorGMMOptions, color_gmm_register, "rigid", colors="required",
           summary="color-assisted probabilistic registration (Danelljan et al. 2016)"),
    Method("density-adaptive", DensityAdaptiveOptions, density_adaptive_register, "rigid",
           summary="probabilistic registration robust to sampling density (Lawin et al. 2018)"),
    Method("bayes", BayesOptions, bayes_register, "rigid",
           summary="variational Bayesian registration with Student-t mixtures (Zhou et al. 2019)"),
)
"""Every registration method by name, in the order of :data:`MethodName`."""

RIGID_METHODS: tuple[str, ...] = tuple(name for name, m in METHODS.items() if m.rigid)


def method_spec(method: str) -> Method:
    """The :class:`Method` named ``method``; an ``InputError`` listing the names otherwise."""
    return METHODS[as_choice(method, "method", tuple(METHODS))]


def options_class(method: str) -> type:
    """The options dataclass of a registration ``method`` (e.g. ``RegistrationOptions`` for "l2e")."""
    return method_spec(method).options


def methods_taking(extra: str) -> tuple[str, ...]:
    """The methods that take ``extra``, in table order: an argument of :data:`EXTRAS` (``"model_normals"``),
    or ``"colors"`` / ``"normals"`` for either set's."""
    if extra in EXTRAS:
        return tuple(name for name, m in METHODS.items() if m.use_of(extra) != "unused")
    return tuple(name for name, m in METHODS.items() if getattr(m, extra) != "unused")
