"""Simulated Annealing of the Eq. 5 error over the model's DOFs (paper Eq. 6, §2.3, Table 1).

Built from small parts in the manner of ``scipy.optimize.dual_annealing``:
the proposal ``j + l·v`` with ``v_i = s(H_i)·r_i`` (re-drawn where the joint
histogram says the angle is implausible, ``H_i < T_h``), the Metropolis
acceptance at temperature τ, and the geometric cooling of τ and l. The loop
itself is compiled (``core._kernels.anneal``); this module validates, prepares
the histogram statistics and reports. :func:`anneal` runs the kernel a fit runs
(``core._kernels.fit_attempt``), without its restarts and refinement.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

import numpy as np

from core import _kernels
from core.error import (
    DEFAULT_EMPTY_VIEW_PENALTY_PX,
    Detections,
    check_fusion,
    check_views,
    view_offsets,
)
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["AnnealParams", "AnnealResult", "StopReason", "anneal", "kernel_params", "search_space"]


class StopReason(enum.Enum):
    """Why the annealing loop ended (paper §2.3)."""

    ITERATIONS = "iterations"  # N_end reached
    BELOW_EPSILON = "below_epsilon"  # E < ε


@dataclass(frozen=True)
class AnnealParams:
    """SA parameters: the paper's Table 1, and the polishing this engine adds to it.

    Parameters
    ----------
    n_end : int
        N_end, iterations at most (Table 1: 35000).
    n_l, n_tau : int
        Iterations between two coolings of the step length l (N_l) and of the
        temperature τ (N_τ).
    tau0, l0 : float
        Initial temperature (units of the Eq. 5 error, pixels) and step-length factor.
    c_l, c_tau : float in (0, 1]
        Cooling factors of l and τ.
    eps : float
        ε, pixels: SA stops once the best Eq. 5 error is below it.
    plausibility_threshold : float in [0, 1)
        T_h, compared with a histogram bin's probability: a proposed angle whose bin
        is below it is drawn again (implausible).
    polish_every : int
        Every that many iterations SA's best and current postures are refined
        (``core.refine``) and the ``E < eps`` stop is tested on them, so that SA ends
        as soon as it has found the basin (see ``core._kernels.anneal``); 0 gives the
        paper's plain SA.
    patience : int
        With polishing, SA also stops after that many polish rounds without lowering
        its best error by 1 % (scipy basin-hopping's ``niter_success``); 0 keeps the
        paper's stop rules alone.
    draws : int
        At every polish round that leaves the best at or above ε, that many postures
        are drawn from the histograms and the one of lowest error is polished as well:
        a restart of the refinement where SA has not found the basin yet; 0 turns
        them off.
    huber_px : float
        The refinement's least-squares radius, pixels, where it starts: it tightens to
        ``core._kernels.MIN_RADIUS_PX`` where a marker lies beyond it and most within.

    The defaults of ``polish_every``, ``patience`` and ``draws`` were chosen on the locust
    benchmarks; docs/ENGINE_NOTES.md has the measurements.
    """

    n_end: int = 35000
    n_l: int = 3500
    n_tau: int = 1500
    tau0: float = 200.0
    l0: float = 1.0
    c_l: float = 0.75
    c_tau: float = 0.75
    eps: float = 1.0
    plausibility_threshold: float = 1e-4
    polish_every: int = 100
    patience: int = 10
    draws: int = 32
    huber_px: float = 1.0

    def __post_init__(self) -> None:
        for name in ("n_end", "n_l", "n_tau"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive whole number, got {value!r}")
        for name in ("polish_every", "patience", "draws"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a whole number >= 0, got {value!r}")
        for name in ("tau0", "l0"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        for name in ("c_l", "c_tau"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in (0, 1], got {getattr(self, name)!r}")
        if not (self.eps >= 0 and math.isfinite(self.eps)):
            raise ValueError(f"eps must be a non-negative number, got {self.eps!r}")
        if not (math.isfinite(self.huber_px) and self.huber_px > 0):
            raise ValueError(f"huber_px must be a positive number, got {self.huber_px!r}")
        if not 0 <= self.plausibility_threshold < 1:
            raise ValueError(
                f"plausibility_threshold must be in [0, 1), got {self.plausibility_threshold!r}"
            )

    def with_iterations(self, n_end: int) -> AnnealParams:
        """These parameters with N_end = ``n_end`` and N_l, N_τ scaled along (paper §3.2).

        >>> AnnealParams().with_iterations(7000).n_l
        700
        """
        ratio = n_end / self.n_end
        return replace(self, n_end=n_end, n_l=max(1, round(self.n_l * ratio)),
                       n_tau=max(1, round(self.n_tau * ratio)))


@dataclass(frozen=True)
class AnnealResult:
    """Best posture found: ``dofs`` (D,) in model order, its Eq. 5 ``error`` in pixels."""

    dofs: np.ndarray
    error: float
    iterations: int
    stop: StopReason


@dataclass(frozen=True)
class SearchSpace:
    """What the SA kernel needs from the histograms, for every DOF (translations included).

    mean, sigma : (D,) float64, start posture and s(H); table : (D, B) probabilities, NaN rows
    for translational DOFs (no histogram); histograms : the histograms they come from.
    """

    mean: np.ndarray
    sigma: np.ndarray
    table: np.ndarray
    histograms: Histograms


def search_space(model: KinematicModel, histograms: Histograms) -> SearchSpace:
    """Start posture (histogram means), step scales s(H) and plausibility tables."""
    if histograms.names != tuple(d.name for d in model.dofs if d.rotational):
        raise ValueError(
            f"histograms are for DOFs {list(histograms.names)}, model '{model.name}' "
            f"has {[d.name for d in model.dofs if d.rotational]}"
        )
    D = len(model.dofs)
    mean = 0.5 * (model.lower + model.upper)
    sigma = (model.upper - model.lower) / math.sqrt(12.0)
    table = np.full((D, histograms.bins), np.nan)
    rot = np.flatnonzero(model.rotational)
    (mean[rot], sigma[rot]), table[rot] = histograms.stats(), histograms.probs
    return SearchSpace(mean, np.maximum(sigma, 1e-6), np.ascontiguousarray(table), histograms)


def kernel_params(params: AnnealParams, sigma: np.ndarray, table: np.ndarray, *, eps: float,
                  refine_result: bool, restarts: int, search_edges: bool = False) -> _kernels.SAParams:
    """``params`` as the kernels take them, for DOFs of step scales ``sigma`` (D,) and
    plausibility ``table`` (D, B) (:class:`SearchSpace`'s, or a part's rows of them); ``eps``
    in pixels; ``refine_result``, ``restarts`` and ``search_edges`` as ``core.fit.FitParams``'s
    ``refine``, ``restarts`` and ``search_edges``."""
    p = params
    return _kernels.SAParams(
        sigma=np.ascontiguousarray(sigma, dtype=np.float64),
        hist=np.ascontiguousarray(table, dtype=np.float64),
        h_min=float(p.plausibility_threshold), n_end=int(p.n_end), n_l=int(p.n_l), n_tau=int(p.n_tau),
        tau0=float(p.tau0), l0=float(p.l0), c_l=float(p.c_l), c_tau=float(p.c_tau), eps=float(eps),
        polish_every=int(p.polish_every), patience=int(p.patience), draws=int(p.draws),
        huber_c=float(p.huber_px), refine_result=bool(refine_result), restarts=int(restarts),
        search_edges=bool(search_edges),
    )


def anneal(
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    space: SearchSpace,
    params: AnnealParams,
    rng: np.random.Generator,
    start: np.ndarray | None = None,
    offsets: np.ndarray | None = None,
    empty_view_penalty_px: float = DEFAULT_EMPTY_VIEW_PENALTY_PX,
    fusion_px: float = 0.0,
) -> AnnealResult:
    """Minimise Eq. 5 for one image by Simulated Annealing.

    One SA run of the kernel a fit runs (``core._kernels.fit_attempt``, no restart, no
    refinement of the result). ``error`` is the plain Eq. 5 error of the best posture; the
    stop is :attr:`StopReason.BELOW_EPSILON` where the attempt's objective (with fusion below
    ``fusion_px``; without fusion, that same Eq. 5 error) ended below ε.

    Parameters
    ----------
    detections : Detections, one group per rig view.
    space : SearchSpace from :func:`search_space` (histogram means, s(H), T_h tables).
    params : AnnealParams (Table 1 by default).
    rng : numpy Generator; the same state gives the same result.
    start : ndarray of shape (D,), optional; the histogram means by default (paper §3.1).
    offsets : ndarray of shape (V, 2), optional, per-view pixel offsets (root tracking).
    fusion_px : markers projecting closer than this are one blob (``core.error``); 0: off.
    """
    check_views(detections, rig)
    q0 = space.mean.copy() if start is None else model._check_postures(start)[0].copy()
    q0 = np.clip(q0, model.lower, model.upper)
    state = rng.integers(1, np.iinfo(np.uint64).max, size=4, dtype=np.uint64, endpoint=True)
    sa = kernel_params(params, space.sigma, space.table, eps=params.eps, refine_result=False, restarts=0)
    image = _kernels.Image.of(detections.kernel_points, detections.start, view_offsets(offsets, rig),
                              penalty=empty_view_penalty_px, fuse_px=check_fusion(fusion_px))
    best, err, objective, it, _ = _kernels.fit_attempt(
        q0, False, _kernels.Bounds(model.lower, model.upper), model.arrays, rig.arrays, image, sa, state,
        np.empty((0, len(q0))))
    stop = StopReason.BELOW_EPSILON if objective < params.eps else StopReason.ITERATIONS
    return AnnealResult(best, float(err), int(it), stop)
