"""Declared options: each field of an options dataclass states its kind, bounds and meaning once.

Every options dataclass of the library declares its fields with :func:`option` and is marked
with :func:`declared`; its ``__post_init__`` calls :func:`check_declared` (then checks what
involves several fields), and :func:`option_specs` hands the same declarations to whoever needs
them: the service derives its form fields and their OpenAPI schema, the CLI its flags, batch
manifests their columns. A new field is one line and appears everywhere.

A class may list fields it renamed in a ``RENAMED_FIELDS`` class attribute (old name -> new
name): the old name is then an ``InputError`` naming the new one, in the constructor
(``VFCOptions(a=1)``) as in option dicts (:func:`reglib._validation.as_options`).

Values may come as Python / JSON values or as text (a form field, a CSV cell, a command-line
argument): :meth:`OptionSpec.parse` reads both with the library's own checks and messages.
"""
from __future__ import annotations

import dataclasses
import difflib
import functools
import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import numpy as np

from ._validation import check_int, check_range
from .errors import InputError

__all__ = ["Kind", "OptionSpec", "check_declared", "declared", "nearest_names", "option", "option_specs",
           "parse_fields"]

T = TypeVar("T")

Kind = Literal["bool", "int", "float", "json", "choice"]
_TRUE = ("true", "1", "yes", "on")
_FALSE = ("false", "0", "no", "off")


@dataclass(frozen=True, slots=True)
class OptionSpec:
    """One option field: its name, kind, default, bounds and one-line meaning.

    Attributes
    ----------
    name : str
        Field name (the service form field, the manifest column; ``--name-with-dashes`` on the CLI).
    kind : {"bool", "int", "float", "json", "choice"}
        "json": a JSON object (a dict of estimator options) or null.
    default : Any
        The default value.
    doc : str
        What the option does, one line.
    low, high : float or None
        Bounds (inclusive unless ``low_open`` / ``high_open``).
    choices : tuple of str
        Allowed values of a "choice".
    optional : bool
        None is allowed too (it then means what the field's docstring says, e.g. "derived from
        the other options"); as text, "", "none" and "null" read as None.
    """

    name: str
    kind: Kind
    default: Any
    doc: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    optional: bool = False

    def check(self, value: Any) -> Any:
        """``value`` if it is valid for this option (a Python / JSON value), else an ``InputError`` naming it."""
        name = self.name
        if value is None and self.optional:
            return None
        if self.kind == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise InputError(f"`{name}` must be a bool, got {value!r}")
            return bool(value)
        if self.kind == "choice":
            if not isinstance(value, str) or value not in self.choices:
                raise InputError(f"`{name}` must be one of {list(self.choices)}, got {value!r}")
            return value
        if self.kind == "json":
            if value is not None and not isinstance(value, dict):
                raise InputError(f"`{name}` must be a dict (a JSON object) of options or None, "
                                 f"got {type(value).__name__}")
            return value
        if self.kind == "int":  # the library's own integer and range checks, with their messages
            low = -(2**63) if self.low is None else int(self.low) + (1 if self.low_open else 0)
            high = None if self.high is None else int(self.high) - (1 if self.high_open else 0)
            return check_int(name, value, low, high)
        check_range(name, value, self.low, self.high, low_open=self.low_open, high_open=self.high_open)
        return value

    def parse(self, value: Any) -> Any:
        """Like :meth:`check`, but text is read first as the kind says ("true", "12", "0.8", '{"beta": 1}')."""
        if isinstance(value, str):
            value = self._from_text(value.strip())
        return self.check(value)

    def _from_text(self, text: str) -> Any:
        name = self.name
        if self.optional and text.lower() in ("", "none", "null"):
            return None
        if self.kind == "bool":
            if text.lower() in _TRUE:
                return True
            if text.lower() in _FALSE:
                return False
            raise InputError(f"`{name}` must be true or false, got {text!r}")
        if self.kind == "int":
            try:
                return int(text)
            except ValueError:
                raise InputError(f"`{name}` must be an integer, got {text!r}") from None
        if self.kind == "float":
            try:
                return float(text)
            except ValueError:
                raise InputError(f"`{name}` must be a number, got {text!r}") from None
        if self.kind == "json":
            if text.lower() in ("", "null", "none"):
                return None
            try:
                return json.loads(text)
            except ValueError:
                raise InputError(f"`{name}` must be a JSON object of options, got {text[:60]!r}") from None
            except RecursionError:  # nested deeper than the parser's recursion limit: no options are that deep
                raise InputError(f"`{name}` is nested too deeply to be a JSON object of options") from None
        return text

    def bounded(self, high: float) -> OptionSpec:
        """This option with a tighter upper bound (a service may accept less than the library)."""
        if self.high is not None and self.high <= high:
            return self
        return dataclasses.replace(self, high=high, high_open=False)


def option(default: Any, *, kind: Kind, doc: str, low: float | None = None, high: float | None = None,
           low_open: bool = False, high_open: bool = False, choices: tuple[str, ...] = (),
           optional: bool = False) -> Any:
    """A dataclass field declared with its :class:`OptionSpec` (kept in the field's metadata)."""
    return dataclasses.field(default=default, metadata={"spec": dict(
        kind=kind, doc=doc, low=low, high=high, low_open=low_open, high_open=high_open, choices=choices,
        optional=optional)})


@functools.cache
def option_specs(cls: type) -> tuple[OptionSpec, ...]:
    """The :class:`OptionSpec` of every field of the options dataclass ``cls``, in declaration order."""
    specs = []
    for f in dataclasses.fields(cls):
        meta = f.metadata.get("spec")
        if meta is None:
            raise TypeError(f"{cls.__name__}.{f.name} is not declared with reglib.options.option()")
        specs.append(OptionSpec(name=f.name, default=f.default, **meta))
    return tuple(specs)


def check_declared(obj: Any) -> None:
    """Check every declared field of the options instance ``obj`` (call from ``__post_init__``)."""
    for spec in option_specs(type(obj)):  # type: ignore[arg-type]  # a class is Hashable; mypy#11470 says not
        spec.check(getattr(obj, spec.name))


def declared(cls: type[T]) -> type[T]:
    """Mark an options dataclass (decorate above ``@dataclass``): every field must be declared.

    Checks at import that each field is declared with :func:`option`, and makes the constructor
    refuse a name listed in the class's ``RENAMED_FIELDS`` with an ``InputError`` naming the new
    one (without it, the old name would be a bare ``TypeError`` about an unexpected keyword).
    """
    option_specs(cls)  # type: ignore[arg-type]  # a class is Hashable; mypy#11470 says not
    renamed: Mapping[str, str] = getattr(cls, "RENAMED_FIELDS", {})
    if renamed:
        cls.__init__ = _refusing_renamed(cls.__init__, renamed, cls.__name__)  # type: ignore[method-assign]  # wraps the constructor on purpose (RENAMED_FIELDS)
    return cls


def _refusing_renamed(init: Callable[..., None], renamed: Mapping[str, str], owner: str) -> Callable[..., None]:
    @functools.wraps(init)
    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
        old = sorted(set(kwargs) & set(renamed))
        if old:
            raise InputError(f"`{owner}` field `{old[0]}` was renamed to `{renamed[old[0]]}`")
        init(self, *args, **kwargs)
    return __init__


def nearest_names(name: str, names: Iterable[str]) -> list[str]:
    """The (at most two) names of ``names`` closest to a misspelled ``name``, nearest first; [] when none is close.

    The same closeness as ``reglib``'s answer to a misspelled flag (:func:`difflib.get_close_matches`).

    >>> nearest_names("ratoi", ["features", "ratio", "seed", "max_ratio"])
    ['ratio']
    >>> nearest_names("zzz", ["ratio", "seed"])
    []
    """
    return difflib.get_close_matches(name, list(names), n=2, cutoff=0.7)


def parse_fields(specs: tuple[OptionSpec, ...], values: Mapping[str, Any], what: str) -> dict[str, Any]:
    """Parse the ``values`` named by ``specs`` (text or JSON values); an unknown name is an ``InputError``."""
    by_name = {s.name: s for s in specs}
    unknown = sorted(set(values) - set(by_name))
    if unknown:
        prefix = f"{what}: " if what else ""
        raise InputError(f"{prefix}unknown option(s) {unknown}; valid options are {list(by_name)}")
    return {k: by_name[k].parse(v) for k, v in values.items()}
