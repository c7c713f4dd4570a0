"""The image path: two images -> features -> robust filter -> dense stage (:func:`match_images`).

- :mod:`reglib.matching.pipeline`: :func:`match_images`, the stages in order.
- :mod:`reglib.matching.multimodal`: the multimodal path's estimate from its putatives (a
  two-stage fit, and the rigid NMI fallback).
- :mod:`reglib.matching.options`: :class:`MatchOptions`, each field declared once.
- :mod:`reglib.matching.request`: :class:`MatchRequest`, one parser of a match request for the
  service, batch manifests and ``reglib match``.
- :mod:`reglib.matching.result`: :class:`ImageMatch`, what ``match_images`` found, and its JSON form.

The features are :mod:`reglib.features`' and the dense stage is :mod:`reglib.dense`.
"""
from .options import DEFAULT_MAX_PIXELS, FEATURES, MatchOptions
from .pipeline import match_images
from .request import REQUEST_FIELDS, MatchRequest, match_request_specs
from .result import ImageMatch

__all__ = ["DEFAULT_MAX_PIXELS", "FEATURES", "REQUEST_FIELDS", "ImageMatch", "MatchOptions", "MatchRequest",
           "match_images", "match_request_specs"]
