"""What a user may give for one option: its help text and bounds, checked with a clear error.

An option is a dataclass field made with :func:`option`; its :class:`Bounds` ride in the
field's metadata, so the options classes (``core.options.FitOptions``,
``core.detect.DetectorParams``) state each option once, and the command line (``cli``)
and the API's schema (``service.schemas``) are generated from them.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import operator
from dataclasses import dataclass
from typing import Any

__all__ = ["Bounds", "OptionError", "bounds_of", "check_options", "option"]

_METADATA_KEY = "bounds"


class OptionError(ValueError):
    """An option's value out of its bounds: ``str()`` is "<name> must be …, got …"."""

    def __init__(self, name: str, problem: str) -> None:
        super().__init__(f"{name} {problem}")
        self.name, self.problem = name, problem


@dataclass(frozen=True)
class Bounds:
    """The values an option takes and what it does.

    kind : bool, int, float, str, or tuple for (u, v) pixel pairs (one per view).
    ge, gt, le, lt : bounds of a number (int, float kinds); a float is also finite.
    words : strings allowed: beside a number ('auto', 'otsu'), or a str option's only values.
    optional : None is allowed (the option is not given).
    max_length : most characters of a str, most pairs of a tuple.
    """

    help: str
    kind: type = float
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    words: tuple[str, ...] = ()
    optional: bool = False
    max_length: int | None = None

    def describe(self) -> str:
        """The allowed values in words, e.g. "'auto' or a number in 0..1000"."""
        if self.kind is bool:
            text = "true or false"
        elif self.kind is str:
            text = (f"one of {', '.join(self.words)}" if self.words
                    else f"a text of 1 to {self.max_length} characters")
        elif self.kind is tuple:
            text = f"one (u, v) pair of finite pixels per view, at most {self.max_length}"
        else:
            number = "an integer" if self.kind is int else "a number"
            words = ", ".join(repr(w) for w in self.words)
            text = (words + " or " if words else "") + number + self._range()
        return text + (" (or none)" if self.optional else "")

    def _range(self) -> str:
        if self.ge is not None and self.le is not None:
            return f" in {_num(self.ge)}..{_num(self.le)}"
        parts = [f"{op} {_num(v)}" for op, v in ((">=", self.ge), (">", self.gt), ("<=", self.le),
                                                 ("<", self.lt)) if v is not None]
        return " " + " and ".join(parts) if parts else ""

    def check(self, name: str, value: Any) -> None:
        """Raise :class:`OptionError` naming ``name`` unless ``value`` is allowed."""
        if not self._allows(value):
            raise OptionError(name, f"must be {self.describe()}, got {value!r}")

    def _allows(self, value: Any) -> bool:
        if value is None:
            return self.optional
        if isinstance(value, str) and value in self.words:
            return True
        if self.kind is bool:
            return isinstance(value, bool)
        if self.kind is str:
            return (isinstance(value, str) and not self.words and 0 < len(value) <= (self.max_length or 0)
                    and value.isprintable())
        if self.kind is tuple:
            return _pairs(value, self.max_length or 0)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral if self.kind is int
                                                     else numbers.Real):
            return False
        if not isinstance(value, numbers.Integral) and not math.isfinite(value):  # an int is finite
            return False
        return all(bound is None or holds(value, bound) for bound, holds in (
            (self.ge, operator.ge), (self.gt, operator.gt), (self.le, operator.le), (self.lt, operator.lt)))


def _num(value: float) -> str:
    return str(value) if isinstance(value, int) else f"{value:g}"


def _pairs(value: Any, most: int) -> bool:
    if not isinstance(value, tuple | list) or not 0 < len(value) <= most:
        return False
    return all(isinstance(p, tuple | list) and len(p) == 2 and all(
        isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x) for x in p)
        for p in value)


def option(default: Any = dataclasses.MISSING, *, help: str, kind: type = float,
           **bounds: Any) -> Any:
    """A dataclass field that is a user-facing option (``Bounds``' arguments besides ``help``)."""
    return dataclasses.field(default=default,
                             metadata={_METADATA_KEY: Bounds(help=help, kind=kind, **bounds)})


def bounds_of(cls: Any) -> dict[str, Bounds]:
    """The options of a dataclass (class or instance), in field order: name → Bounds."""
    return {f.name: f.metadata[_METADATA_KEY] for f in dataclasses.fields(cls)
            if _METADATA_KEY in f.metadata}


def check_options(obj: Any) -> None:
    """Check every option of the dataclass instance ``obj`` (OptionError naming the first bad one)."""
    for name, bounds in bounds_of(obj).items():
        bounds.check(name, getattr(obj, name))
