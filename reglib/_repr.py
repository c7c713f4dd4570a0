"""Short ``repr`` of the result types: what a result is, in one line, not its arrays.

A result printed at the prompt should say what was found (counts, shapes, the verdict); its arrays
are a ``to_dict()`` or an attribute away. The client's results print the same way.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["short_repr"]


def _value_repr(value: Any) -> str:
    """A number to 4 significant digits, an array as its shape and dtype, a mapping item by item."""
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    if isinstance(value, np.ndarray):
        return f"<array {'x'.join(map(str, value.shape)) or 'scalar'} {value.dtype}>"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k!r}: {_value_repr(v)}" for k, v in value.items()) + "}"
    if isinstance(value, tuple):
        return "(" + ", ".join(_value_repr(v) for v in value) + ("," if len(value) == 1 else "") + ")"
    return repr(value)


def short_repr(obj: Any, names: tuple[str, ...]) -> str:
    """``Type(name=value, ...)`` of the named attributes of ``obj``, the None ones left out.

    Parameters
    ----------
    obj : object
        The result.
    names : tuple of str
        Attribute (or property) names, in the order shown.

    Returns
    -------
    str
        One line; arrays appear as ``<array 480x640x2 float32>``.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> short_repr(SimpleNamespace(n=3, sigma=0.123456, flow=np.zeros((4, 5, 2), np.float32), why=None),
    ...            ("n", "sigma", "flow", "why"))
    'SimpleNamespace(n=3, sigma=0.1235, flow=<array 4x5x2 float32>)'
    """
    parts = [f"{name}={_value_repr(getattr(obj, name))}" for name in names if getattr(obj, name) is not None]
    return f"{type(obj).__name__}({', '.join(parts)})"
