"""``mocap fit``'s and ``mocap detect``'s options, generated from ``core.options.FitOptions``.

Each option of FitOptions (the detector's flattened in: ``--threshold``, ``--blur`` …)
becomes a typer option with its default and help, so the command line cannot drift
from the library and the API. Values that are a number or a word ('auto', 'otsu') and
the root's start ('u,v;u,v') are taken as text and read here; every bound is checked by
FitOptions, and its error names the command-line flag.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Annotated, Any

import typer

from core.bounds import Bounds, OptionError, bounds_of
from core.detect import DetectorParams
from core.options import FitOptions

__all__ = [
    "detector_options", "detector_parameters", "fit_options", "fit_parameters", "flag", "flags_in_errors",
    "markdown_table", "with_options",
]

_DETECTOR = "detector"


def flag(name: str) -> str:
    """The command-line flag of an option: ``marker_diameter_px`` → ``--marker-diameter-px``."""
    return "--" + name.replace("_", "-")


def _defaults(cls: Any) -> dict[str, Any]:
    return {f.name: f.default for f in dataclasses.fields(cls) if f.default is not dataclasses.MISSING}


def _as_text(bounds: Bounds) -> bool:
    """Taken as text and read by :func:`_read`: a number or a word, or (u, v) pairs."""
    return bounds.kind is tuple or (bounds.kind in (int, float) and bool(bounds.words))


def _parameter(name: str, bounds: Bounds, default: Any) -> inspect.Parameter:
    help_text = f"{bounds.help}: {bounds.describe()}"
    if bounds.kind is bool:
        annotation: Any = Annotated[bool, typer.Option(flag(name), help=help_text)]
    else:
        kind: Any = str if _as_text(bounds) or bounds.kind is str else bounds.kind
        if bounds.kind is tuple:
            help_text = f"{bounds.help}: 'u,v;u,v', one pair per view"
        annotation = Annotated[kind | None if bounds.optional else kind, typer.Option(help=help_text)]
        if _as_text(bounds) and default is not None:
            default = str(default)
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)


def _parameters(cls: Any) -> list[inspect.Parameter]:
    defaults = _defaults(cls)
    return [_parameter(name, bounds, defaults[name]) for name, bounds in bounds_of(cls).items()]


def fit_parameters() -> list[inspect.Parameter]:
    """Every option of FitOptions as a keyword parameter, the detector's in its place."""
    params = _parameters(FitOptions)
    at = [f.name for f in dataclasses.fields(FitOptions)].index(_DETECTOR)  # options precede it
    return params[:at] + _parameters(DetectorParams) + params[at:]


def with_options(parameters: Callable[[], list[inspect.Parameter]]) -> Callable[[Callable[..., None]],
                                                                                Callable[..., None]]:
    """Give a command taking ``**options`` the generated ``parameters`` in their place (typer reads
    the command's ``__signature__``)."""

    def decorate(command: Callable[..., None]) -> Callable[..., None]:
        own = [p for p in inspect.signature(command, eval_str=True).parameters.values()
               if p.kind is not inspect.Parameter.VAR_KEYWORD]
        command.__signature__ = inspect.Signature([*own, *parameters()])  # type: ignore[attr-defined]
        return command

    return decorate


@contextmanager
def flags_in_errors() -> Iterator[None]:
    """An option's error names its flag (``--blur must be …``), as the user typed it."""
    try:
        yield
    except OptionError as exc:
        raise ValueError(f"{flag(exc.name)} {exc.problem}") from None


def _read(name: str, bounds: Bounds, value: Any) -> Any:
    """A value as typed on the command line → the option's value (bounds are FitOptions')."""
    if value is None or not _as_text(bounds) or value in bounds.words:
        return value
    try:
        if bounds.kind is tuple:
            pairs = tuple(tuple(float(x) for x in pair.split(",")) for pair in value.split(";"))
            if any(len(p) != 2 for p in pairs):
                raise ValueError
            return pairs
        return float(value)
    except ValueError:
        expected = "'u,v;u,v', one pair of numbers per view" if bounds.kind is tuple else bounds.describe()
        raise OptionError(name, f"must be {expected}, got {value!r}") from None


def _read_all(cls: Any, values: dict[str, Any]) -> dict[str, Any]:
    return {name: _read(name, bounds, values[name]) for name, bounds in bounds_of(cls).items()}


def detector_options(values: dict[str, Any]) -> DetectorParams:
    """The detector's options of ``mocap fit`` or ``mocap detect`` (errors name the flag)."""
    with flags_in_errors():
        return DetectorParams(**_read_all(DetectorParams, values))


def fit_options(values: dict[str, Any]) -> FitOptions:
    """``mocap fit``'s options (keyword values of :func:`fit_parameters`) as FitOptions."""
    detector = detector_options(values)
    with flags_in_errors():
        return FitOptions(**_read_all(FitOptions, values), detector=detector)


def detector_parameters() -> list[inspect.Parameter]:
    """The detector's options alone (``mocap detect``)."""
    return _parameters(DetectorParams)



def markdown_table() -> str:
    """The options as the Markdown table of docs/OPTIONS.md (a test keeps the two equal)."""
    rows = ["| option (API JSON) | `mocap fit` | default | values | what it does |",
            "|---|---|---|---|---|"]
    options = [(name, bounds, _defaults(FitOptions)[name]) for name, bounds in bounds_of(FitOptions).items()]
    detector = [(f"{_DETECTOR}.{name}", bounds, _defaults(DetectorParams)[name])
                for name, bounds in bounds_of(DetectorParams).items()]
    for name, bounds, default in options + detector:
        rows.append(f"| `{name}` | `{flag(name.split('.')[-1])}` | `{json.dumps(default)}` | "
                    f"{bounds.describe()} | {bounds.help} |")
    return "\n".join(rows) + "\n"
