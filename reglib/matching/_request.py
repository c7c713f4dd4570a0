"""``MatchRequest``: one parser for "match these two images with these options".

The service's form, batch manifests (their check and their workers) and ``reglib match`` all read
a match request through :meth:`MatchRequest.from_fields`: ``features``, ``method``, ``seed`` and
the fields of :class:`~reglib.MatchOptions`, given as text (a form field, a CSV cell, a command-line
argument) or as JSON values, checked with the library's own rules and messages.
:func:`match_request_specs` lists those fields with their kinds and bounds, which is what the
shells derive their forms, flags and columns from.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from .._validation import as_options
from ..errors import InputError
from ..options import OptionSpec, option_specs, parse_fields
from ..robust import METHODS, L2EOptions, VFCOptions
from ._options import FEATURES, MatchOptions
from ._pipeline import match_images
from ._result import ImageMatch

__all__ = ["MatchRequest", "match_request_specs", "REQUEST_FIELDS"]

REQUEST_FIELDS = ("features", "method", "seed")
MAX_SEED = 2**53


def match_request_specs() -> tuple[OptionSpec, ...]:
    """``features``, ``method``, ``seed``, then every :class:`MatchOptions` field, with kinds and bounds."""
    return (OptionSpec("features", "choice", "sift", "feature kind", choices=tuple(FEATURES)),
            OptionSpec("method", "choice", "l2e", "robust estimator", choices=tuple(METHODS)),
            OptionSpec("seed", "int", 0, "random seed, recorded in the answer", low=0, high=MAX_SEED),
            *option_specs(MatchOptions))


@dataclass(frozen=True)
class MatchRequest:
    """A checked match request: what :func:`reglib.match_images` is called with.

    Attributes
    ----------
    features, method : str
        As :func:`reglib.match_images` takes them.
    seed : int
        The seed (``rng``), recorded in the answer.
    options : MatchOptions
        The options, absent fields at their defaults.
    given : dict
        The option fields that were given (JSON values), for :meth:`to_fields`.
    """

    features: str = "sift"
    method: str = "l2e"
    seed: int = 0
    options: MatchOptions = field(default_factory=MatchOptions)
    given: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_fields(cls, values: Mapping[str, Any], *, what: str = "request") -> MatchRequest:
        """Parse ``values`` (text or JSON values by field name); unknown names and bad values are errors.

        The estimator options (``filter``, ``dense_filter``) are checked against the options class
        of ``method`` too, so a misspelled estimator field fails here, not after the features.

        Raises
        ------
        InputError
            Naming the field.

        Examples
        --------
        >>> r = MatchRequest.from_fields({"ratio": "0.9", "dense": "false", "seed": "3"})
        >>> r.options.ratio, r.options.dense, r.seed
        (0.9, False, 3)
        """
        if not isinstance(values, Mapping):
            raise InputError(f"{what} must be a mapping of field names to values, got {type(values).__name__}")
        parsed = parse_fields(match_request_specs(), values, what)
        features = parsed.pop("features", "sift")
        method = parsed.pop("method", "l2e")
        seed = parsed.pop("seed", 0)
        options = as_options(parsed, MatchOptions)
        estimator = L2EOptions if method == "l2e" else VFCOptions
        for name in ("filter", "dense_filter"):
            if parsed.get(name) is not None:
                as_options(parsed[name], estimator, name)
        return cls(features=features, method=method, seed=seed, options=options, given=parsed)

    def to_fields(self) -> dict[str, Any]:
        """The request as JSON values: ``features``, ``method``, ``seed`` and the given options."""
        return {"features": self.features, "method": self.method, "seed": self.seed, **self.given}

    def run(self, image_a: Any, image_b: Any, *, mask_a: Any = None, mask_b: Any = None) -> ImageMatch:
        """:func:`reglib.match_images` on two images with this request."""
        return match_images(image_a, image_b, features=self.features, method=self.method,  # type: ignore[arg-type]  # plain strs, checked by match_images
                            options=self.options, rng=self.seed,
                            mask_a=mask_a, mask_b=mask_b)
