"""Compiled kernels of the joint-angle histograms (``core.histogram``): Eq. 4 and the circular
statistics. They call no other kernel, so they are cached on their own (``core._kernels``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def eq4_update(probs, counts, bins) -> None:
    """Eq. 4 in place, one measurement per row: ``H_N = ((N-1)·H_{N-1} + Δ) / N``."""
    for r in range(probs.shape[0]):
        counts[r] += 1.0
        keep = (counts[r] - 1.0) / counts[r]
        for k in range(probs.shape[1]):
            probs[r, k] *= keep
        probs[r, bins[r]] += 1.0 / counts[r]


@njit(cache=True, nogil=True)
def circular_stats(probs, lower, upper, sin_c, cos_c):
    """Circular mean (range coordinates) and spread s(H) of each row, degrees.

    Mean: direction of Σ p·(cos, sin) of the bin centres, expressed in
    ``[lower, lower + 360)``; a mean beyond ``upper`` goes to the
    nearer range end on the circle; no direction (|Σ| < 1e-9) gives the range
    midpoint. Spread: RMS angular distance of the bins to the unclamped mean;
    an empty row gives the spread of a uniform distribution over its range.
    ``sin_c``, ``cos_c`` (B,): sine and cosine of the bin centres.
    """
    R, B = probs.shape
    width = 360.0 / B
    means, stds = np.empty(R), np.empty(R)
    for r in range(R):
        lo, hi = lower[r], upper[r]
        s = c = total = 0.0
        for k in range(B):
            s += probs[r, k] * sin_c[k]
            c += probs[r, k] * cos_c[k]
            total += probs[r, k]
        raw = lo + (math.degrees(math.atan2(s, c)) - lo) % 360.0
        mean = raw
        if mean > hi:
            mean = hi if (mean - hi) < (lo + 360.0 - mean) else lo
        undirected = math.hypot(s, c) < 1e-9
        means[r] = 0.5 * (lo + hi) if undirected else mean
        centre = 0.5 * (lo + hi) if undirected else raw
        if total > 0.0:
            var = 0.0
            c0 = centre % 360.0
            for k in range(B):  # d: bin centre - c0 wrapped into [-180, 180), no fmod per bin
                d = (k + 0.5) * width - c0
                d = d - 360.0 if d >= 180.0 else (d + 360.0 if d < -180.0 else d)
                var += probs[r, k] * d * d
            stds[r] = math.sqrt(var / total)
        else:
            stds[r] = (hi - lo) / math.sqrt(12.0)
    return means, stds
