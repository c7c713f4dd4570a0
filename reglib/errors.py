"""Exceptions raised by reglib.

``InputError`` is for input that is wrong (it names the argument, what was expected and what
came); ``EstimationError`` is for a numerical failure on input that was acceptable.
"""
from __future__ import annotations

__all__ = ["ReglibError", "InputError", "EstimationError", "ImageTooLarge", "UnsupportedFormat"]


class ReglibError(Exception):
    """Base class of every exception raised on purpose by reglib."""


class InputError(ReglibError, ValueError):
    """An argument is malformed: wrong shape, type, value or option name."""


class EstimationError(ReglibError, RuntimeError):
    """The numerics failed on acceptable input (e.g. a singular system that no fallback fixed)."""


class ImageTooLarge(InputError):
    """An image (or upload) is over the configured pixel or byte limit."""


class UnsupportedFormat(InputError):
    """An encoded image is in a format that is not allowed (PNG, JPEG, TIFF, BMP, WebP are)."""
