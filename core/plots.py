"""Angle plots of a fitted sequence: what each DOF did, and what the histograms learnt.

Two figures, each written as PNG and SVG (:func:`write_plots`):

- ``angles``: one axis per DOF, its angle (or root translation) over time; the
  central :data:`SHADED_MASS` of the final histogram (Eq. 4) shaded, the model's
  range as the axis limits; over-threshold images marked ×, ambiguous ones
  (angles.csv's optional ``alternative_deg``) ○, re-analysed ones (attempts > 1)
  as ticks along the axis' bottom edge.
- ``histograms``: one axis per rotational DOF, the starting distribution of the job
  and the final one (Eq. 4 before and after), over the DOF's range.

matplotlib is imported by these functions only, so that ``import core`` stays fast; they
draw on their own ``Figure`` with the Agg renderer (no pyplot state, no display), so
several threads or processes may plot at once.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from core.fit import Status
from core.histogram import Histograms
from core.model import KinematicModel
from core.results import AnglesTable

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "MAX_PLOT_DOFS", "PLOTS_DIR", "SHADED_MASS", "angles_figure", "histogram_interval",
    "histograms_figure", "write_plots",
]

PLOTS_DIR = "plots"  # under a results directory
SHADED_MASS = 0.9  # the central share of the final histogram shaded behind each angle
# One axis per DOF, 1.6 inches each: more would make a figure no one reads (and a large image).
MAX_PLOT_DOFS = 64
_AXIS_HEIGHT_IN = 1.6
_WIDTH_IN = 10.0
_DPI = 100
# The overlay's colours (core.overlay.MARK_BGR), as RGB.
_OVER_THRESHOLD = "#ff0000"
_AMBIGUOUS = "#ff00ff"
_REANALYSED = "#ff8c00"


def histogram_interval(histograms: Histograms, index: int, mass: float = SHADED_MASS) -> tuple[float, float]:
    """The central ``mass`` of one DOF's distribution, in its range coordinates (degrees).

    Bin centres are placed in ``[lower, lower + 360)`` (where the DOF's values lie) and
    the interval runs between the (1 - mass)/2 and (1 + mass)/2 quantiles of the bins.

    >>> h = Histograms.uniform(KinematicModel.from_xml(
    ...     '<model name="m"><joint name="j"><dof axis="z" name="a" min="350" max="370"/></joint>'
    ...     '<marker name="M" joint="j" x="1" y="0" z="0"/></model>'))
    >>> [round(x) for x in histogram_interval(h, 0, 0.5)]
    [355, 365]
    """
    lower = histograms.lower[index]
    width = 360.0 / histograms.bins
    centres = lower + np.mod((np.arange(histograms.bins) + 0.5) * width - lower, 360.0)
    order = np.argsort(centres)
    cumulative = np.cumsum(histograms.probs[index, order])
    if cumulative[-1] <= 0:
        return float(lower), float(histograms.upper[index])
    cumulative /= cumulative[-1]
    lo = centres[order][np.searchsorted(cumulative, (1.0 - mass) / 2.0)]
    hi = centres[order][min(np.searchsorted(cumulative, (1.0 + mass) / 2.0), len(order) - 1)]
    return float(lo - width / 2.0), float(hi + width / 2.0)


def angles_figure(table: AnglesTable, model: KinematicModel, final: Histograms | None) -> Figure:
    """One axis per DOF (model order): its values over time, with the marks of the module doc."""
    _check_dofs(len(model.dofs))
    if table.dof_names != model.dof_names:
        raise ValueError(f"angles.csv has DOF columns {table.dof_names}, the model {model.dof_names}")
    from matplotlib.figure import Figure
    from matplotlib.transforms import blended_transform_factory

    figure = Figure(figsize=(_WIDTH_IN, _AXIS_HEIGHT_IN * len(model.dofs) + 0.6), dpi=_DPI,
                    layout="constrained")
    axes = figure.subplots(len(model.dofs), 1, sharex=True, squeeze=False)[:, 0]
    over = np.array([s is Status.OVER_THRESHOLD for s in table.statuses], dtype=bool)
    ambiguous = np.isfinite(table.alternative_deg)
    reanalysed = table.attempts > 1
    histogram_row = {name: r for r, name in enumerate(final.names)} if final is not None else {}
    t = table.times
    for d, (ax, dof) in enumerate(zip(axes, model.dofs, strict=True)):
        y = table.dofs[:, d]
        if dof.name in histogram_row:
            lo, hi = histogram_interval(final, histogram_row[dof.name])
            ax.axhspan(lo, hi, color="#1f77b4", alpha=0.15, lw=0,
                       label=f"final histogram, central {SHADED_MASS:.0%}")
        ax.plot(t, y, color="#1f77b4", lw=1.0, label="fitted value")
        ax.plot(t[over], y[over], "x", color=_OVER_THRESHOLD, ms=6, label="over threshold")
        ax.plot(t[ambiguous], y[ambiguous], "o", mfc="none", color=_AMBIGUOUS, ms=7, label="ambiguous")
        bottom = blended_transform_factory(ax.transData, ax.transAxes)
        ax.plot(t[reanalysed], np.full(reanalysed.sum(), 0.04), "|", color=_REANALYSED, ms=8,
                transform=bottom, label="re-analysed")
        ax.set_ylim(dof.min, dof.max)
        _name(ax, dof.name)
        ax.set_ylabel("deg" if dof.rotational else model.units)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    legend: dict = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(label, handle)
    figure.legend(legend.values(), legend.keys(), loc="outside upper center", fontsize="small", ncols=5)
    axes[0].set_title(f"{model.name}: {len(t)} images; × over threshold {over.sum()}, "
                      f"○ ambiguous {ambiguous.sum()}, | re-analysed {reanalysed.sum()}")
    return figure


def histograms_figure(start: Histograms, final: Histograms) -> Figure:
    """One axis per rotational DOF: the starting and final distributions over its range."""
    if start.names != final.names or start.bins != final.bins:
        raise ValueError(f"starting histograms of DOFs {list(start.names)} do not match the final "
                         f"ones {list(final.names)}")
    _check_dofs(len(final.names))
    from matplotlib.figure import Figure

    figure = Figure(figsize=(_WIDTH_IN, _AXIS_HEIGHT_IN * max(len(final.names), 1) + 0.6), dpi=_DPI,
                    layout="constrained")
    if not final.names:
        figure.suptitle("no rotational DOF: no histograms")
        return figure
    axes = figure.subplots(len(final.names), 1, squeeze=False)[:, 0]
    width = 360.0 / final.bins
    for r, (ax, name) in enumerate(zip(axes, final.names, strict=True)):
        lower, upper = final.lower[r], final.upper[r]
        centres = lower + np.mod((np.arange(final.bins) + 0.5) * width - lower, 360.0)
        order = np.argsort(centres)
        x = centres[order]
        ax.fill_between(x, 100.0 * final.probs[r, order], step="mid", color="#1f77b4", alpha=0.5,
                        label=f"final (N = {final.counts[r]:g})")
        ax.step(x, 100.0 * start.probs[r, order], where="mid", color="0.3", lw=1.0,
                label=f"start (N = {start.counts[r]:g})")
        ax.set_xlim(lower, upper)
        _name(ax, name)
        ax.set_ylabel("% per bin")
        ax.legend(loc="upper right", fontsize="small")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("angle (deg, in the DOF's range)")
    figure.suptitle(f"{final.model}: joint-angle histograms (Eq. 4), {final.bins} bins")
    return figure


def _name(ax: Axes, name: str) -> None:
    """A DOF's name at the top left inside its axis: a y label of a whole animal's long DOF
    names (``R1_metatarsus_pitch (deg)``) ran past the axis' height and was clipped."""
    ax.text(0.005, 0.96, name, transform=ax.transAxes, va="top", fontsize="small",
            bbox={"facecolor": "white", "alpha": 0.7, "lw": 0, "pad": 1})


def write_plots(out: Path, table: AnglesTable, model: KinematicModel, start: Histograms,
                final: Histograms) -> list[str]:
    """Write ``angles.{png,svg}`` and ``histograms.{png,svg}`` into ``out``; return their names.

    SVGs keep their text as text and carry no date, so the same input gives the same file.
    """
    import matplotlib

    out.mkdir(parents=True, exist_ok=True)
    names = []
    figures = {"angles": angles_figure(table, model, final), "histograms": histograms_figure(start, final)}
    with matplotlib.rc_context({"svg.hashsalt": "mocap", "svg.fonttype": "none"}):
        for stem, figure in figures.items():
            for ext in ("png", "svg"):
                figure.savefig(out / f"{stem}.{ext}", format=ext,
                               metadata={"Date": None} if ext == "svg" else None)
                names.append(f"{stem}.{ext}")
    return names


def _check_dofs(n: int) -> None:
    if n > MAX_PLOT_DOFS:
        raise ValueError(f"plots draw one axis per DOF, at most {MAX_PLOT_DOFS}; this model has {n}")
