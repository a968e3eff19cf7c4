"""Joint-angle histograms: the adaptive constraints of paper §2.2 (Eq. 4, FORMATS §4).

One distribution of ``bins`` bins (default 360) per rotational DOF; bin i covers
``[i·w, (i+1)·w)`` degrees with ``w = 360 / bins`` after wrapping the angle into
[0, 360). Each distribution carries its count N of Eq. 4, so that two
histograms merge as the count-weighted mean with counts added; merging the
prior with the *observed* histograms of two halves of a sequence gives exactly
the histogram updated over the whole sequence.

Means and spreads are taken on the circle and expressed in the DOF's own
range coordinates (``min ≤ value ≤ max``, ``max`` may exceed 360), so a range
such as 300..420 needs no special case.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core import _histogram_kernels
from core._files import decimal, parse_decimal
from core.model import KinematicModel
from core.xmlio import attribute, parse

__all__ = ["MAX_BINS", "MAX_COUNT", "HistogramError", "Histograms"]

DEFAULT_BINS = 360
# Most bins per distribution: 0.1° each. The search reads every bin of every DOF for
# s(H) and the means of each image, and a file's ``bins`` must not decide how much
# memory is allocated; a lab's 360 (1°) is far below.
MAX_BINS = 3600
# Largest count N of Eq. 4 a file or a prior may give. Huge counts are a use (a prior of 1e20
# never moves), but near float's end two merged counts overflowed: 1e308 + 1e308 became inf,
# was written as "inf", and the file no longer read. Sums of 1e300 stay finite.
MAX_COUNT = 1e300
_VALUE = re.compile(r"\S+")


class HistogramError(ValueError):
    """A histogram file or operation that does not fit the model."""


@dataclass
class Histograms:
    """Per-DOF angle distributions with their Eq. 4 counts.

    Attributes
    ----------
    model : str
        Name of the model the histograms belong to.
    names : tuple of str
        Rotational DOF names, in model-file order.
    lower, upper : ndarray of shape (R,), float64, degrees
        The DOF ranges (range coordinates for means).
    probs : ndarray of shape (R, B), float64
        Each row a probability distribution (sum 1), or all zeros when its count is 0.
    counts : ndarray of shape (R,), float64
        N of Eq. 4 per DOF (measurements plus the prior's weight).
    """

    model: str
    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    probs: np.ndarray
    counts: np.ndarray

    # ---- construction ---------------------------------------------------------------------
    @classmethod
    def uniform(
        cls, model: KinematicModel, *, prior_weight: float = 100.0, bins: int = DEFAULT_BINS
    ) -> Histograms:
        """Uniform over each DOF's plausible range, zero elsewhere, worth ``prior_weight`` counts."""
        if bins < 1:
            raise ValueError(f"bins must be at least 1, got {bins}")
        if not (0 < prior_weight <= MAX_COUNT):
            raise ValueError(f"prior_weight must be a positive finite number, at most {MAX_COUNT:g} "
                             f"(MAX_COUNT), got {prior_weight}")
        empty = cls.empty(model, bins=bins)
        for r in range(len(empty.names)):
            mask = _range_mask(empty.lower[r], empty.upper[r], bins)
            empty.probs[r, mask] = 1.0 / mask.sum()
        empty.counts[:] = prior_weight
        return empty

    @classmethod
    def empty(cls, model: KinematicModel, *, bins: int = DEFAULT_BINS) -> Histograms:
        """No measurements yet (count 0): the neutral element of :meth:`merge`."""
        _check_bins_limit(bins)
        rot = [d for d in model.dofs if d.rotational]
        return cls(
            model=model.name,
            names=tuple(d.name for d in rot),
            lower=np.array([d.min for d in rot], dtype=np.float64),
            upper=np.array([d.max for d in rot], dtype=np.float64),
            probs=np.zeros((len(rot), bins)),
            counts=np.zeros(len(rot)),
        )

    def copy(self) -> Histograms:
        return Histograms(self.model, self.names, self.lower.copy(), self.upper.copy(),
                          self.probs.copy(), self.counts.copy())

    @property
    def bins(self) -> int:
        return self.probs.shape[1]

    # ---- Eq. 4 -----------------------------------------------------------------------------
    def update(self, angles: np.ndarray) -> None:
        """Eq. 4 in place for one measurement per DOF: ``H_N = ((N-1)·H_{N-1} + Δ) / N``.

        Parameters
        ----------
        angles : ndarray of shape (R,), float64, degrees, rotational DOFs in model order.
        """
        a = np.asarray(angles, dtype=np.float64)
        if a.shape != self.counts.shape:
            raise ValueError(f"angles must have shape {self.counts.shape}, got {a.shape}")
        _histogram_kernels.eq4_update(self.probs, self.counts, self.bin_index(a))

    def bin_index(self, angles: np.ndarray) -> np.ndarray:
        """Bin of each angle (degrees, any interval) after wrapping into [0, 360)."""
        b = np.floor(np.mod(angles, 360.0) / (360.0 / self.bins)).astype(np.int64)
        return np.minimum(b, self.bins - 1)

    def merge(self, *others: Histograms) -> Histograms:
        """Count-weighted mean of ``self`` and ``others``, counts added (FORMATS §4)."""
        out = self.copy()
        for other in others:
            out._check_compatible(other)
            total = out.counts + other.counts
            w = np.divide(out.counts, total, out=np.zeros_like(total), where=total > 0)
            out.probs = out.probs * w[:, None] + other.probs * (1.0 - w)[:, None]
            out.probs[total == 0] = 0.0
            out.counts = total
        return out

    def _check_compatible(self, other: Histograms) -> None:
        if other.names != self.names or other.bins != self.bins:
            raise HistogramError(
                f"cannot merge histograms of DOFs {list(other.names)} ({other.bins} bins) into "
                f"{list(self.names)} ({self.bins} bins)"
            )

    # ---- statistics used by the search ----------------------------------------------------
    def means(self) -> np.ndarray:
        """(R,) circular mean of each DOF, in its range coordinates (degrees).

        A mean falling outside the range goes to the nearer range end; a
        distribution with no direction (uniform over the circle, or empty) gives
        the range midpoint.
        """
        return self.stats()[0]

    def stds(self) -> np.ndarray:
        """(R,) standard deviation s(H) of each DOF about its circular mean, degrees.

        The spread is measured about the unclamped mean (the spread of the
        distribution, not of its range). An empty distribution gives the spread
        of a uniform one over the range.
        """
        return self.stats()[1]

    def stats(self) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`means`, :meth:`stds`) in one pass: the search needs both for every image."""
        sin_c, cos_c = _centre_trig(self.bins)
        return _histogram_kernels.circular_stats(self.probs, self.lower, self.upper, sin_c, cos_c)

    # ---- FORMATS §4 --------------------------------------------------------------------------
    def to_xml(self) -> str:
        lines = [f'<histograms model="{attribute(self.model)}" bins="{self.bins}">']
        for name, count, p in zip(self.names, self.counts, self.probs, strict=True):
            values = " ".join(decimal(v) for v in p)
            lines.append(f'  <dof name="{attribute(name)}" count="{decimal(count)}">{values}</dof>')
        lines.append("</histograms>")
        return "\n".join(lines) + "\n"

    @classmethod
    def from_xml(cls, source: str | bytes | Path, model: KinematicModel) -> Histograms:
        """Read ``histograms.xml`` for ``model``: one ``<dof>`` per rotational DOF of the model."""
        root = parse(source, "histogram file", HistogramError)
        if root.tag != "histograms":
            raise HistogramError(f"root element is <{root.tag}>, expected <histograms>")
        raw_bins = root.get("bins", str(DEFAULT_BINS)).strip()
        if not (raw_bins.isascii() and raw_bins.isdigit()):
            raise HistogramError(f"bins={root.get('bins')!r} is not a whole number")
        bins = int(raw_bins)
        if bins < 1:
            raise HistogramError(f"bins={bins} must be at least 1")
        _check_bins_limit(bins)
        names = tuple(d.name for d in model.dofs if d.rotational)
        parsed: dict[str, tuple[float, np.ndarray]] = {}
        for el in root.findall("dof"):
            name = el.get("name", "")
            if name not in names:
                raise HistogramError(f"dof '{name}' is not a rotational DOF of model '{model.name}'")
            if name in parsed:
                raise HistogramError(f"dof '{name}' appears twice")
            parsed[name] = _parse_dof(el, name, bins)
        missing = [n for n in names if n not in parsed]
        if missing:
            raise HistogramError(f"no histogram for DOF(s) {', '.join(missing)}")
        out = cls.empty(model, bins=bins)
        for r, name in enumerate(out.names):
            out.counts[r], out.probs[r] = parsed[name]
        return out


def _parse_dof(el, name: str, bins: int) -> tuple[float, np.ndarray]:
    where = f"dof '{name}'"
    text = el.text or ""
    tokens = text.split(maxsplit=bins)
    if len(tokens) != bins:
        # More than ``bins``: the last token holds the rest of the text; count, don't split it.
        got = len(tokens) if len(tokens) < bins else bins + sum(1 for _ in _VALUE.finditer(tokens[-1]))
        raise HistogramError(f"{where}: expected {bins} values, got {got}")
    try:
        count = parse_decimal(el.get("count", "nan"))
        values = np.array([parse_decimal(v) for v in tokens], dtype=np.float64)
    except ValueError as exc:
        raise HistogramError(f"{where}: {exc}") from None
    if not (math.isfinite(count) and count >= 0):
        raise HistogramError(f"{where}: count must be a non-negative number")
    if count > MAX_COUNT:
        raise HistogramError(f"{where}: count {count:g} is more than {MAX_COUNT:g} (MAX_COUNT)")
    if not np.all(np.isfinite(values)) or np.any(values < 0):
        raise HistogramError(f"{where}: values must be non-negative numbers")
    total = values.sum()
    if count > 0 and abs(total - 1.0) > 1e-6:
        raise HistogramError(f"{where}: values sum to {total:.6g}, not 1")
    return count, (values / total if total > 0 else values)


def _check_bins_limit(bins: int) -> None:
    if bins > MAX_BINS:
        raise HistogramError(f"bins={bins} is more than {MAX_BINS} (MAX_BINS)")


@functools.cache
def _centre_trig(bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Sine and cosine of the bin centres, (bins,) each: constants of the bin count."""
    centres = np.radians((np.arange(bins) + 0.5) * (360.0 / bins))
    return np.sin(centres), np.cos(centres)


def _range_mask(lo: float, hi: float, bins: int) -> np.ndarray:
    """Bins that overlap [lo, hi] on the circle by a positive length.

    A fractional ``min`` such as 120.7 keeps bin 120 plausible for 120.7..121;
    a range ending exactly on a bin edge does not reach into the next bin.
    """
    width = 360.0 / bins
    rel = (np.arange(bins) * width - lo) % 360.0  # bin start, relative to lo
    return (rel < (hi - lo)) | (rel + width > 360.0)
