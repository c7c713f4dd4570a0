"""Robust estimators of a smooth transformation from putative matches (L2E, VFC)."""
from .filter import METHODS, filter_matches
from .result import FilterResult
from .l2e import L2EOptions
from .vfc import VFCOptions

__all__ = ["FilterResult", "filter_matches", "L2EOptions", "VFCOptions", "METHODS"]
