"""The image path: two images -> features -> robust filter -> dense stage (:func:`match_images`).

- :mod:`reglib.matching._pipeline`: :func:`match_images`, the stages in order.
- :mod:`reglib.matching._multimodal`: the multimodal path's estimate from its putatives (a
  two-stage fit, and the rigid NMI fallback).
- :mod:`reglib.matching._options`: :class:`MatchOptions`, each field declared once.
- :mod:`reglib.matching._request`: :class:`MatchRequest`, one parser of a match request for the
  service, batch manifests and ``reglib match``.
- :mod:`reglib.matching._result`: :class:`ImageMatch`, what ``match_images`` found, and its JSON form.

The features are :mod:`reglib.features`' and the dense stage is :mod:`reglib.dense`.
"""
from ._options import DEFAULT_MAX_PIXELS, FEATURES, MatchOptions
from ._pipeline import match_images
from ._request import REQUEST_FIELDS, MatchRequest, match_request_specs
from ._result import ImageMatch

__all__ = ["DEFAULT_MAX_PIXELS", "FEATURES", "REQUEST_FIELDS", "ImageMatch", "MatchOptions", "MatchRequest",
           "match_images", "match_request_specs"]
