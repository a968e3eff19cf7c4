"""Fitting one image: SA + refinement, its alternatives, and its re-analysis (paper §3, §4).

Every image is fitted on its own (paper §4): an attempt's random stream depends only on
``(seed, sample, attempt)`` (:func:`image_stream`), so an image fitted by any worker, in
any order, gives the same posture. :func:`first_attempt` is an image's first fit (from
the histograms' means, or from warm starts its chunk gives), :func:`needs_reanalysis`
decides whether it needs another, and :func:`reanalyse_image` is one more attempt from a
posture drawn from the histograms, keeping the better. How a sequence's images go through
these steps (chunks, merge, re-analysis, finish) is ``core.sequence``.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from core import _kernels
from core.ambiguity import (
    Candidate,
    FlipGeometry,
    angle_gaps,
    distinct,
    flip_alternatives,
)
from core.anneal import AnnealParams, SearchSpace, search_space
from core.ceilings import hidden_charge
from core.error import (
    DEFAULT_EMPTY_VIEW_PENALTY_PX,
    Detections,
    check_fusion,
    check_views,
    marker_errors,
    outside_error,
    view_offsets,
)
from core.histogram import Histograms
from core.model import KinematicModel
from core.part_objective import part_objective
from core.rig import Rig
from core.threads import one_blas_thread
from core.treefit import (
    TreeFlips,
    attempt_kernel,
    fit_tree,
    refine_whole,
    refine_without_lost,
    refit_tree,
    search_floor,
    tree_flip_alternatives,
)
from core.undetermined import (
    UNDETERMINED_DEG,
    borrowed_projections,
    crossed_markers,
    fused_projections,
    hidden_projections,
    residual_tolerance,
    rigid_markers,
    scatter_error,
    typical_inflation,
    undetermined_alternative,
    unseen_markers,
)

__all__ = [
    "FitParams",
    "ImageFit",
    "Status",
    "alternative_tolerance",
    "first_attempt",
    "fit_image",
    "flip_geometry",
    "image_status",
    "image_stream",
    "needs_reanalysis",
    "reanalyse_image",
    "seen_from_after",
    "witness_tolerance",
]

# A minimum lower than another by this much (px) or less ties with it: the arithmetic's
# noise, as between a posture and its mirror in one orthographic view.
TIE_PX = 1e-6


class Status(enum.StrEnum):
    """Per-image outcome, as written in the ``status`` column of angles.csv (FORMATS §3)."""

    OK = "ok"
    OVER_THRESHOLD = "over_threshold"
    NO_DETECTIONS = "no_detections"


@dataclass(frozen=True)
class FitParams:
    """Everything that decides a fit besides the data, the model, the rig and the seed.

    The resolved internal parameters: fit from Python with ``core.options.FitOptions`` and
    ``build_fit``, which give what ``mocap fit`` and the API minimise (their defaults are the
    user-facing ones; these defaults are the paper's plain Eq. 5, ``fusion_px`` 0).

    error_threshold_px : an image whose Eq. 5 error per compared marker projection
        (:meth:`ImageFit.error_per_marker`) is above this is re-analysed and, if it stays
        above, reported ``over_threshold``; per projection, so that it means the same for
        8 or 160 projections (the paper's 10 px over 4 markers × 2 views is 1.25 px).
    max_attempts : fits per image at most, the first included (paper: 5).
    refine : polish SA's best posture by bounded least squares (``core.refine``).
    empty_view_penalty_px : Eq. 5 charge per marker of a view without detections.
    fusion_px : markers projecting closer than this may be one blob, and every view is
        read apart and with its closer pairs merged (``core.error``;
        :func:`core.error.fusion_distance` of the marker diameter; 0 = the paper's Eq. 5).
        Reported errors are plain Eq. 5.
    restarts : within one attempt, SA runs again (from a posture drawn from the
        histograms) at most this many times while the objective stays >= ε: SA's
        own convergence test says it is in a local minimum, whatever the threshold.
    alternative_tolerance_px : postures in other minima (depth flips, the previous
        image's posture refined) scoring within this of an image's fit are kept as its
        alternatives, and the best-scoring one becomes the fit (``core.ambiguity``); per
        8 compared marker projections (the paper's 4 markers × 2 views), scaled up to an
        image's own, and widened where the image's residual cannot tell postures apart
        (:func:`alternative_tolerance`); 0 turns the search off.
    choose_by_continuity : at the end of a sequence, choose each image's posture
        among its alternatives by continuity with its neighbours (``core.ambiguity``).
    outlier_factor : an image whose objective is more than this times the sequence's
        median (and above where the search itself stops, ``core.treefit.search_floor``:
        ε, or the smallest of its parts' for a tree) is re-analysed as if over the threshold; 0: only
        the threshold (the paper).
    search_edges : SA charges a marker beyond its view's edge as unseen, as every step after
        it does (``core._kernels.fit_attempt``); False, SA reads plain Eq. 5 there. Set by
        :func:`reanalyse_image` where the kept posture has projections beyond the edges.
    """

    anneal: AnnealParams = field(default_factory=AnnealParams)
    error_threshold_px: float = 1.25
    max_attempts: int = 5
    refine: bool = True
    empty_view_penalty_px: float = DEFAULT_EMPTY_VIEW_PENALTY_PX
    fusion_px: float = 0.0
    restarts: int = 2
    alternative_tolerance_px: float = 0.5
    choose_by_continuity: bool = True
    outlier_factor: float = 3.0
    search_edges: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.error_threshold_px) and self.error_threshold_px > 0):
            raise ValueError(
                f"error_threshold_px must be a positive number, got {self.error_threshold_px!r}"
            )
        if isinstance(self.max_attempts, bool) or not isinstance(self.max_attempts, int) or not (
            1 <= self.max_attempts <= 100
        ):
            raise ValueError(f"max_attempts must be a whole number in 1..100, got {self.max_attempts!r}")
        if not (math.isfinite(self.empty_view_penalty_px) and self.empty_view_penalty_px >= 0):
            raise ValueError(
                f"empty_view_penalty_px must be a non-negative number, got "
                f"{self.empty_view_penalty_px!r}"
            )
        check_fusion(self.fusion_px)
        if isinstance(self.restarts, bool) or not isinstance(self.restarts, int) or not (
            0 <= self.restarts <= 100
        ):
            raise ValueError(f"restarts must be a whole number in 0..100, got {self.restarts!r}")
        for name in ("alternative_tolerance_px", "outlier_factor"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a number >= 0, got {value!r}")


@dataclass(frozen=True)
class ImageFit:
    """The accepted posture of one image (one row of angles.csv).

    dofs : (D,) float64 in model order, NaN when there were no detections.
    error : Eq. 5 error of ``dofs`` in pixels (the ``error_px`` column), NaN without detections.
    objective : the minimised error (Eq. 5 with marker fusion when enabled), used to keep
        the best attempt.
    attempts : how many times the image was fitted (1 + re-analyses; 0 without detections).
    status : ok, over_threshold or no_detections.
    iterations : SA iterations over all attempts.
    detections : number of detected points in each view.
    alternatives : other postures the image supports almost as well (depth flips,
        ``core.ambiguity``), worse objective first excluded: sorted by objective.
    settled : a re-analysis from a drawn start ended in this posture's minimum
        (:func:`reanalyse_image`), so :func:`needs_reanalysis` asks for no more attempts.
    charged : pixels of ``objective`` that markers the image does not show cost at the
        empty-view penalty (``core.ceilings.hidden_charge``), at the posture the attempts
        kept (before the choice by continuity): left out of the sequence's typical objective
        (``core.sequence.typical_objective``).
    outside : (how many, pixels of ``error``) of the marker projections that lie beyond
        their view's region by more than half a marker's diameter (``core.error.outside_error``:
        a limb out of the frame), at the posture the attempts kept: an image over the
        threshold by those alone is not re-analysed (:func:`needs_reanalysis`).
    """

    sample: int
    dofs: np.ndarray
    error: float
    objective: float
    attempts: int
    status: Status
    iterations: int
    detections: tuple[int, ...]
    alternatives: tuple[Candidate, ...] = ()
    settled: bool = False
    charged: float = 0.0
    outside: tuple[int, float] = (0, 0.0)

    def as_candidate(self) -> Candidate:
        """The posture as one of the image's candidates (``core.ambiguity``), beside its
        ``alternatives``."""
        return Candidate(self.dofs, self.error, self.objective)

    def compared(self, n_markers: int) -> int:
        """Marker projections compared with detections: markers × views with any detection."""
        return _compared(self.detections, n_markers)

    def charged_beyond(self, params: FitParams) -> float:
        """Pixels of ``objective`` that the projections beyond their views' regions
        (``outside``) cost, the empty-view penalty each: the same in every posture that
        leaves them there, so no measure of how well the posture fits."""
        return params.empty_view_penalty_px * self.outside[0]

    def error_per_marker(self, n_markers: int) -> float:
        """``error`` divided by :meth:`compared` (FORMATS §3 ``error_per_marker_px``); NaN
        without detections.

        >>> fit = ImageFit(0, np.zeros(1), 6.0, 6.0, 1, Status.OK, 1, (3, 0, 2))
        >>> fit.compared(3), fit.error_per_marker(3)
        (6, 1.0)
        """
        compared = self.compared(n_markers)
        return self.error / compared if compared and math.isfinite(self.error) else math.nan

    def alternative_deg(self, rotational: np.ndarray) -> float:
        """Largest absolute rotational DOF difference (degrees, the shorter way round) between
        the posture and its best alternative (FORMATS §3 ``alternative_deg``); NaN when the
        image has none.

        Alternatives are postures whose objective is within :func:`alternative_tolerance`
        of the fit: other minima, or a posture at least ``core.undetermined.UNDETERMINED_DEG``
        away in a DOF the image does not determine (``core.undetermined``).

        >>> alt = Candidate(np.array([10.0, 350.0]), 0.1, 0.1)
        >>> fit = ImageFit(0, np.array([30.0, 5.0]), 0.1, 0.1, 1, Status.OK, 1, (4,), (alt,))
        >>> fit.alternative_deg(np.array([True, True]))
        20.0
        """
        gaps = self._alternative_gaps(rotational)
        return math.nan if gaps is None else float(gaps.max())

    def alternative_dof(self, rotational: np.ndarray) -> int | None:
        """Index (model-file order) of the rotational DOF in which the best distinct
        alternative is farthest from the posture, the one :meth:`alternative_deg` measures;
        None when the image has none.

        >>> alt = Candidate(np.array([10.0, 350.0]), 0.1, 0.1)
        >>> fit = ImageFit(0, np.array([30.0, 5.0]), 0.1, 0.1, 1, Status.OK, 1, (4,), (alt,))
        >>> fit.alternative_dof(np.array([True, True])), fit.alternative_dof(np.array([False, True]))
        (0, 1)
        """
        gaps = self._alternative_gaps(rotational)
        return None if gaps is None else int(np.flatnonzero(rotational)[np.argmax(gaps)])

    def _alternative_gaps(self, rotational: np.ndarray) -> np.ndarray | None:
        """Absolute differences (degrees) of the rotational DOFs between the posture and its
        best distinct alternative (least objective of those more than
        ``core.ambiguity.DISTINCT_DEG`` away in some angle), or None without one.

        Why distinct: the depth flip search tells its refined flips apart at 1 degree, and a
        flip refined back next to the fit stays a candidate of the choice by continuity, but
        is no other posture that explains the image: reported, they made 6 of 8 noise-free
        mouse images and 8 of 15 two-camera hexapod images ambiguous, 1-4.5 degrees apart.
        """
        distinct_ones = [c for c in self.alternatives if distinct(c.dofs, self.dofs, rotational)]
        if not distinct_ones:
            return None
        best = min(distinct_ones, key=lambda c: c.objective)
        return angle_gaps(best.dofs, self.dofs)[rotational]

    def to_record(self) -> dict:
        """The fit as JSON-safe values (None for NaN), for a database row or a message.

        >>> fit = ImageFit(3, np.array([1.5, np.nan]), 0.25, 0.2, 1, Status.OK, 500, (4, 3))
        >>> ImageFit.from_record(fit.to_record()).to_record() == fit.to_record()
        True
        """
        return {
            "sample": self.sample, "dofs": [_json_float(v) for v in self.dofs],
            "error": _json_float(self.error), "objective": _json_float(self.objective),
            "attempts": self.attempts, "status": self.status.value,
            "iterations": self.iterations, "detections": list(self.detections),
            "alternatives": [
                {"dofs": [_json_float(v) for v in c.dofs], "error": _json_float(c.error),
                 "objective": _json_float(c.objective), "minimum": c.minimum}
                for c in self.alternatives
            ],
            "settled": self.settled, "charged": self.charged,
            "outside": [self.outside[0], self.outside[1]],
        }

    @classmethod
    def from_record(cls, record: dict) -> ImageFit:
        """Inverse of :meth:`to_record`."""
        return cls(
            sample=int(record["sample"]),
            dofs=_float_array(record["dofs"]),
            error=_float(record["error"]),
            objective=_float(record["objective"]),
            attempts=int(record["attempts"]), status=Status(record["status"]),
            iterations=int(record["iterations"]),
            detections=tuple(int(c) for c in record["detections"]),
            alternatives=tuple(
                Candidate(_float_array(c["dofs"]), _float(c["error"]), _float(c["objective"]),
                          bool(c.get("minimum", True)))
                for c in record.get("alternatives", ())
            ),
            settled=bool(record.get("settled", False)),
            charged=float(record.get("charged", 0.0)),
            outside=_outside(record.get("outside", (0, 0.0))),
        )


_UINT64 = (1 << 64) - 1


def image_stream(seed: int, sample: int, attempt: int) -> np.ndarray:
    """The random stream of one attempt on one image: a xoshiro256** state, (4,) uint64.

    It depends only on ``(seed, sample, attempt)``, so a chunk fitted anywhere,
    in any order, draws the same numbers as a single process would.
    """
    return _kernels.stream_state(np.uint64(seed & _UINT64), np.uint64(sample), np.uint64(attempt))


def fit_image(
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    space: SearchSpace,
    params: FitParams,
    stream: np.ndarray,
    draw_start: bool = False,
    offsets: np.ndarray | None = None,
    warm: np.ndarray | None = None,
    ceilings: Callable[[], Mapping[str, float]] | None = None,
) -> tuple[np.ndarray, float, float, int, np.ndarray, np.ndarray]:
    """One attempt on one image: SA from the histogram means (paper §3.1), then refinement.

    ``draw_start`` starts from a posture drawn from the histograms instead
    (re-analysis, so that an attempt does not retrace the first one's path).
    The refined posture is kept only if it does not raise the fitted objective
    (Eq. 5 with marker fusion when ``params.fusion_px`` > 0). While the
    objective stays at or above ε, SA is restarted from a posture drawn from
    the histograms, up to ``params.restarts`` times, keeping the best. The whole
    attempt runs compiled (``core._kernels.fit_attempt``).

    Parameters
    ----------
    stream : the attempt's random state from :func:`image_stream`; advanced in place.
    offsets : (V, 2) per-view pixel offsets (root tracking), optional.
    warm : (k, D) warm starts, optional (the chunk's previous postures,
        ``core.sequence.fit_chunk``): for a tree, refined on this image first per part, the
        first that reaches twice the part's ε replaces its SA (``core.warm_start.warm_start``).
        A single chain always runs SA: it costs about a millisecond there, and a warm start
        that reaches ε in a wrong minimum would carry that minimum on to the next images.
    ceilings : for a tree, gives per part name the objective per compared projection under
        which its warm start replaces SA too (``core.ceilings.warm_ceilings`` of the previous
        image), called only where a part's warm start misses twice its ε.

    Returns
    -------
    (dofs (D,), plain Eq. 5 error in pixels, minimised objective, SA iterations, searched
    (D,) bool: for a tree, False for the DOFs of the parts a warm start placed, standing in
    for SA under twice their ε, True elsewhere (``core.treefit._searched``); a chain's every
    DOF where SA ran; runs (r, D): a chain's SA runs' final postures, the first run's first,
    (0, D) for a tree)
    """
    check_views(detections, rig)
    off = view_offsets(offsets, rig)
    if model.tree is not None:
        return (*fit_tree(detections, model, rig, model.tree, space, params, stream, draw_start, off,
                          warm, ceilings), np.empty((0, len(model.dofs))))
    dofs, error, objective, iterations, runs = attempt_kernel(
        np.arange(len(model.dofs)), model.arrays, detections.kernel_points, detections.start,
        model, rig, space, params, params.anneal.eps, stream, draw_start, off,
    )
    return dofs, float(error), float(objective), int(iterations), np.full(len(dofs), iterations > 0), runs


def flip_geometry(model: KinematicModel, rig: Rig) -> FlipGeometry | TreeFlips:
    """What an image's depth-flip search (``core.ambiguity``) needs of ``model`` seen through
    ``rig``: built once per chunk, not per image."""
    geometry = FlipGeometry.of(model, rig)
    return geometry if model.tree is None else TreeFlips.of(geometry, model)


def first_attempt(
    det: Detections,
    sample: int,
    *,
    model: KinematicModel,
    rig: Rig,
    histograms: Histograms,
    params: FitParams,
    seed: int,
    geometry: FlipGeometry | TreeFlips,
    offsets: np.ndarray | None = None,
    warm: np.ndarray | None = None,
    ceilings: Callable[[], Mapping[str, float]] | None = None,
    carried: np.ndarray | None = None,
    previous: float = math.nan,
) -> ImageFit:
    """Image ``sample``'s first fit (attempt 1, stream :func:`image_stream` ``(seed, sample,
    1)``) under ``histograms``, with its alternatives; ``no_detections`` without any point.

    geometry : :func:`flip_geometry`, computed once per chunk.
    offsets : this image's (V, 2) view offsets (root tracking), optional.
    warm : (k, D) warm starts from the chunk's previous images (:func:`fit_image`), optional.
    ceilings : per part of a tree, where its warm start stands in for SA (:func:`fit_image`).
    carried : (k, D) the previous image's alternatives, optional: refined on this image,
        the best that scores within the tolerance is reported as an alternative
        (:func:`_warm_alternatives`).
    previous : the objective (px) of the image the warm starts come from: a warm-started fit
        far above it is searched again without them (:func:`_warm_then_cold`); NaN: never.
    """
    counts = tuple(det.counts.tolist())
    if not any(counts):
        nan = np.full(len(model.dofs), np.nan)
        return ImageFit(sample, nan, math.nan, math.nan, 0, Status.NO_DETECTIONS, 0, counts)
    best, alternatives, its, _ = _attempt(
        det, model, rig, search_space(model, histograms), params, image_stream(seed, sample, 1),
        False, offsets, geometry, warm, ceilings, carried=carried, previous=previous,
    )
    status = image_status(best.error, counts, len(model.markers), params)
    charged, outside = _unshown(best.dofs, det, model, rig, params, offsets)
    return ImageFit(sample, best.dofs, best.error, best.objective, 1, status, its, counts,
                    alternatives, charged=charged, outside=outside)


def _unshown(dofs: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, params: FitParams,
             offsets: np.ndarray | None) -> tuple[float, tuple[int, float]]:
    """``ImageFit.charged`` and ``ImageFit.outside`` of the posture ``dofs`` an image keeps."""
    outside = _beyond_edges(dofs, det, model, rig, params, offsets)
    return hidden_charge(dofs, det, model, rig, params, view_offsets(offsets, rig), outside[0]), outside


def _beyond_edges(dofs: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, params: FitParams,
                  offsets: np.ndarray | None) -> tuple[int, float]:
    """``core.error.outside_error`` of posture ``dofs`` as the objective of ``params`` reads it
    (its fusion distance and penalty): ``ImageFit.outside``."""
    return outside_error(dofs, det, model=model, rig=rig, offsets=offsets, fusion_px=params.fusion_px,
                         empty_view_penalty_px=params.empty_view_penalty_px)


def _attempt(det, model, rig, space, params, stream, draw_start, offsets, geometry, warm=None,
             ceilings=None, keep=None, carried=None, typical=math.nan, previous=math.nan):
    """fit_image, then its alternatives: (best candidate, the others, SA iterations, settled).

    ``keep`` (D,), a tree's kept posture, makes the attempt a re-analysis part by part
    (``core.treefit.refit_tree`` given the sequence's typical objective ``typical``, whose
    ``settled`` this returns; False otherwise).

    ``warm`` holds warm starts (:func:`fit_image`; the chunk's previous postures,
    ``core.sequence.fit_chunk``): at 50-200 Hz the previous image's posture is usually near
    the truth, and where it reaches twice ε SA is skipped. Alternatives are the depth flips
    of the fit (``core.ambiguity``) and, where SA ran and left its basin, the previous
    posture refined on this image, when it lands in a distinct minimum scoring within the
    tolerance: a fit that jumped into another minimum that explains the image as well (the
    paper's Fig. 9) gets the truth as its alternative, and the choice by continuity can take
    it. A warm-started fit keeps its depth flips as alternatives, so a previous posture in a
    wrong minimum that this image still supports can be corrected by that choice too. A
    chain's other SA runs that ended in another minimum within the tolerance, at least
    ``core.undetermined.UNDETERMINED_DEG`` from the fit, are alternatives as well
    (:func:`_run_alternatives`).
    Without another minimum distinct from the best (``core.ambiguity.distinct``: a refined
    flip may land next to it), a posture at least ``core.undetermined.UNDETERMINED_DEG``
    away in a DOF the image does not determine (``core.undetermined``) is the alternative:
    looked for where the residual widens the tolerance, and in every image of a model with
    DOFs no posture determines (``model.identifiability``).
    """
    settled = False
    if keep is None:
        dofs, error, objective, its, searched, runs = _warm_then_cold(
            det, model, rig, space, params, stream, draw_start, offsets, warm, ceilings, previous)
    else:
        check_views(det, rig)
        runs = np.empty((0, len(model.dofs)))
        dofs, error, objective, its, settled = refit_tree(
            det, model, rig, model.tree, space, params, stream, view_offsets(offsets, rig), keep, typical)
    fit = Candidate(dofs, error, objective)
    others = []
    seen = _seen_error(error, _beyond_edges(dofs, det, model, rig, params, offsets))
    tolerance = alternative_tolerance(params, det, model, seen, len(model.dofs))
    if tolerance > 0:
        flips = flip_alternatives if model.tree is None else tree_flip_alternatives
        others = flips(
            fit, det, model=model, rig=rig, geometry=geometry, tolerance_px=tolerance,
            fusion_px=params.fusion_px, empty_view_penalty_px=params.empty_view_penalty_px,
            huber_px=params.anneal.huber_px, offsets=offsets,
        )
        if warm is not None:
            others += _warm_alternatives(fit, others, warm, carried, searched, det, model, rig,
                                         params, tolerance, offsets)
        others += _run_alternatives(fit, others, runs, det, model, rig, params, tolerance, offsets)
    ranked = sorted([fit, *others], key=lambda c: c.objective)
    return ranked[0], _witnessed(ranked[0], tuple(ranked[1:]), det, model, rig, params, offsets), its, settled


def _witnessed(best: Candidate, alternatives: tuple[Candidate, ...], det: Detections, model: KinematicModel,
               rig: Rig, params: FitParams, offsets: np.ndarray | None) -> tuple[Candidate, ...]:
    """``alternatives`` of an image's kept posture ``best``, and where a posture the choice by
    continuity may keep (``best`` or an alternative that is a minimum) has no candidate
    distinct from it (``core.ambiguity.distinct``), the witness of a DOF the image does not
    determine (:func:`_undetermined_witness`) after them, if there is one.

    Every posture the choice may keep, not ``best`` alone: alternatives a few degrees apart
    along a valley leave one of them, chosen, with none distinct, though the valley reaches
    far. A random tree whose rolls no posture determines had its best 6° from one
    alternative and 2.6° from another; the choice took the second, 38° off the truth, and
    the image was ``ok`` with nothing flagged (docs/BENCH_SUBJECTS.md, stop 56). The witness
    lies at least ``core.undetermined.UNDETERMINED_DEG`` (10°) from ``best``, so it is
    distinct from any posture within :data:`~core.ambiguity.DISTINCT_DEG` (5°) of it."""
    members = (best, *alternatives)
    rot = model.rotational
    if all(any(distinct(c.dofs, o.dofs, rot) for o in members if o is not c)
           for c in members if c.minimum):
        return alternatives
    witness = _undetermined_witness(best, det, model, rig, params, offsets)
    return alternatives if witness is None else (*alternatives, witness)


def _seen_error(error: float, outside: tuple[int, float]) -> float:
    """A posture's plain Eq. 5 ``error`` (px) without what its projections beyond their
    view's edge add (``outside``, :func:`_beyond_edges`): the residual that widens the
    tolerance of its alternatives. Eq. 5 charges such a projection its distance to a blob inside the
    frame, often hundreds of pixels that tell nothing of how closely the image fixes the
    posture: read as residual, they widened the tolerance until postures 20-30 px above the
    fit were its alternatives, and the choice by continuity took one 45° off
    (docs/BENCH_SUBJECTS.md, stop 53)."""
    return error - outside[1]


def _warm_then_cold(det: Detections, model: KinematicModel, rig: Rig, space: SearchSpace,
                    params: FitParams, stream: np.ndarray, draw_start: bool, offsets: np.ndarray | None,
                    warm: np.ndarray | None, ceilings: Callable[[], Mapping[str, float]] | None,
                    previous: float) -> tuple[np.ndarray, float, float, int, np.ndarray, np.ndarray]:
    """:func:`fit_image` from the warm starts ``warm``; where a tree's fit ends more than the
    error threshold (``params.error_threshold_px`` per compared projection) above
    ``previous``, the objective of the image the warm starts come from, :func:`fit_image`
    again without them, the lower objective kept (SA iterations summed). The warm start is
    one more start, not a replacement for the search. Measured from the previous image, not
    from zero: under sliding skin markers, or with a marker hidden in every image, most
    images are over the threshold, and their warm starts are right.

    Why: where the animal jumps between images, a free root's warm start, refined, can
    stand its three markers on three other blobs at its ε; every branch then hangs from a
    wrong base and SA leaves each far above its own, and re-analysis, part by part given
    the kept posture, never searches a root that its own markers explain. A random tree
    seen by two cameras was left 50-100° off, over the threshold, in its next 20 images,
    whose cold fits were right (docs/BENCH_SUBJECTS.md, random trees)."""
    fitted = fit_image(det, model=model, rig=rig, space=space, params=params, stream=stream,
                       draw_start=draw_start, offsets=offsets, warm=warm, ceilings=ceilings)
    if warm is None or model.tree is None:  # a chain's fit runs SA whatever the warm starts
        return fitted
    limit = params.error_threshold_px * _compared(tuple(det.counts.tolist()), len(model.markers))
    if not fitted[2] > previous + limit:
        return fitted
    cold = fit_image(det, model=model, rig=rig, space=space, params=params, stream=stream,
                     draw_start=draw_start, offsets=offsets)
    kept = cold if cold[2] < fitted[2] else fitted
    return (*kept[:3], fitted[3] + cold[3], *kept[4:])


def _run_alternatives(fit: Candidate, others: list[Candidate], runs: np.ndarray, det: Detections,
                      model: KinematicModel, rig: Rig, params: FitParams, tolerance: float,
                      offsets: np.ndarray | None) -> list[Candidate]:
    """A chain's SA runs' final postures ``runs`` (r, D), refined on the image, that land in
    another minimum within ``tolerance`` of the fit's objective: at least
    ``core.undetermined.UNDETERMINED_DEG`` from the fit and more than
    :data:`~core.ambiguity.DISTINCT_DEG` from ``others`` and from each other in some
    rotational DOF. Minima the choice by continuity may take. Runs nearer the fit ended in
    its valley: where the image does not determine a DOF, the witness
    (:func:`_undetermined_witness`) says how far that valley reaches, and a run a few
    degrees along it would stand in for it.

    Why: SA restarts from drawn postures while its best run stays above ε, and keeps the
    lowest. With a model a little off the animal (segment lengths measured by hand) no
    posture reaches ε, and where a jump in the movement leaves no warm start near, another
    run's minimum can be the truth's a fraction of a pixel above the one kept: the stick
    insect with its model 2 % off kept a posture 24° off, ``ok``, while its second run
    ended 1.7° from the truth (docs/BENCH_SUBJECTS.md)."""
    rot, off = model.rotational, view_offsets(offsets, rig)
    found: list[Candidate] = []

    def new(q: np.ndarray) -> bool:
        return (angle_gaps(q, fit.dofs)[rot].max(initial=0.0) >= UNDETERMINED_DEG
                and all(distinct(q, c.dofs, rot) for c in (*others, *found)))

    for start in runs:
        if not new(start):
            continue
        q, error, objective = refine_whole(start.copy(), det, model, rig, params, off)
        if objective <= fit.objective + tolerance and new(q):
            found.append(Candidate(q, error, objective))
    return found


def _undetermined_witness(fit: Candidate, det: Detections, model: KinematicModel, rig: Rig,
                          params: FitParams, offsets: np.ndarray | None) -> Candidate | None:
    """An image's fit with no other minimum may still not determine a DOF: a posture
    ``core.undetermined.UNDETERMINED_DEG`` away within the one-DOF tolerance, or None.

    Looked for where the residual, not the fixed floor, sets the tolerance (markers off the
    model): on clean footage the flat directions are the depth flips', and the search costs
    a Jacobian of the whole model. A model whose markers cannot determine some DOF in any
    posture (``core.identifiability``) leaves it undetermined in every image, however clean:
    there the search always runs. The residual is read without the projections that look
    hidden (``core.undetermined.scatter_error``): a marker hidden from a camera is not
    scatter, and a noise-free image with one would otherwise read as sliding skin. Another
    minimum's tolerance (:func:`_attempt`) keeps the plain error: read without them, it
    dropped flip alternatives that the choice by continuity needed (docs/BENCH_SUBJECTS.md).
    The scatter is never above the fit's plain error (it leaves out hidden projections and
    views without detections), so an image whose plain error does not widen the tolerance,
    most clean ones, is passed over without reading it, unless a marker is unseen (hidden
    from every camera, or from all but one of three or more:
    ``core.undetermined.unseen_markers``): however clean, the image does not place the DOFs
    only that marker places (a spider's claw hidden from all four cameras left its
    metatarsus 44° off, ``ok``, with no witness).
    """
    off = view_offsets(offsets, rig)
    penalty = params.empty_view_penalty_px
    unseen = np.zeros(len(model.markers), dtype=bool)
    projected = rig.project(model.marker_positions(fit.dofs)) + off[:, None, :]
    crossed = crossed_markers(projected, det, params.fusion_px, rigid_markers(model))
    if fit.error > penalty or crossed.any():  # else no marker can be unseen
        distances = marker_errors(projected, det)
        if crossed.any() or hidden_projections(distances, penalty).any():
            unseen = unseen_markers(distances, penalty, borrowed_projections(projected, det),
                                    fused_projections(projected, det, params.fusion_px), crossed)
    if not unseen.any() and _witness_readings(params, det, model, fit.error) is None:
        return None
    scatter = scatter_error(fit.dofs, det, model, rig, off, penalty, params.fusion_px)
    readings = _witness_readings(params, det, model, scatter)
    if readings is None and not unseen.any():
        return None
    _, residual, inflate = readings or (*witness_tolerance(params, det, model, scatter), True)
    return undetermined_alternative(
        fit, det, model=model, rig=rig, floor_px=params.alternative_tolerance_px,
        residual_px=residual, inflate=inflate or bool(unseen.any()), fusion_px=params.fusion_px,
        empty_view_penalty_px=penalty, huber_px=params.anneal.huber_px, offsets=offsets,
        unseen=unseen,
    )


def _witness_readings(params: FitParams, det: Detections, model: KinematicModel,
                      scatter: float) -> tuple[float, float, bool] | None:
    """:func:`witness_tolerance` of an image of residual ``scatter`` (px) where the
    undetermined-DOF witness is looked for in it, and whether its residual is read as 3D
    scatter (below); else None. The search is on where the residual, read as the markers'
    own 3D scatter, widens the tolerance beyond the fixed floor, or the model has DOFs that
    no posture determines; and in a tree seen in two views, read on the floor alone.

    Two views: a marker's depth then rests on one pair of rays, and a branch can turn along
    them through a valley that stays within the floor with no residual at all; a third view
    pins it. A random tree with two cameras was left 10-13° off, ``ok``, without an
    alternative in four clean images (docs/BENCH_SUBJECTS.md, random trees). Not in a single
    chain: its SA runs that end elsewhere in the valley are its alternatives
    (:func:`_run_alternatives`), and the search would double its cost.

    As 3D scatter because the witness widens each DOF's tolerance so
    (``core.undetermined.shared_scatter_inflation``, about
    ``core.undetermined.typical_inflation``): read as scatter independent in every
    projection, the residual of many markers in many views stays under the floor while
    sliding markers move some DOF's minimum tens of degrees, and nothing was flagged
    (docs/BENCH_SUBJECTS.md, the free fly)."""
    floor, residual = witness_tolerance(params, det, model, scatter)
    compared = _compared(tuple(det.counts.tolist()), len(model.markers))
    widened = residual * typical_inflation(compared, len(model.markers), len(model.dofs))
    scattered = widened > floor or bool(model.identifiability.undetermined)
    if floor > 0 and (scattered or (det.views_seen == 2 and model.tree is not None)):
        return floor, residual, scattered
    return None


def witness_tolerance(params: FitParams, det: Detections, model: KinematicModel,
                      scatter: float) -> tuple[float, float]:
    """:func:`tolerance_readings` of the one-DOF intervals the undetermined-DOF witness reads,
    from the image's ``scatter`` (``core.undetermined.scatter_error``): one interval per
    rotational DOF, all holding together, since an image must be trusted in every DOF at once
    (``core.undetermined.interval_chi2``)."""
    return tolerance_readings(params, det, model, scatter, 1, int(np.count_nonzero(model.rotational)))


def alternative_tolerance(params: FitParams, det: Detections, model: KinematicModel,
                          error: float, tested_dofs: int) -> float:
    """Pixels of objective within which another posture is an alternative of an image's fit
    of Eq. 5 error ``error`` (the plain error for another minimum; for one DOF's interval
    ``core.undetermined.scatter_error``): the larger of :func:`tolerance_readings`. Clean
    footage (0.05 px a projection) keeps the fixed tolerance; sliding skin markers (1 px)
    widen it.
    """
    return max(tolerance_readings(params, det, model, error, tested_dofs))


def tolerance_readings(params: FitParams, det: Detections, model: KinematicModel,
                       error: float, tested_dofs: int, intervals: int = 1) -> tuple[float, float]:
    """The two readings of :func:`alternative_tolerance`, pixels: the fixed floor,
    ``params.alternative_tolerance_px`` per 8 compared marker projections (never less), and
    what the image's own residual cannot tell apart for postures differing in
    ``tested_dofs`` DOFs (``core.undetermined.residual_tolerance``: ``len(model.dofs)`` for
    another minimum, 1 for one DOF's interval, ``intervals`` of them holding together).
    Both 0 when ``params.alternative_tolerance_px`` is 0 (the search is off).
    """
    if params.alternative_tolerance_px == 0:
        return 0.0, 0.0
    compared = _compared(tuple(det.counts.tolist()), len(model.markers))
    return (params.alternative_tolerance_px * max(1.0, compared / 8.0),
            residual_tolerance(error, compared, len(model.dofs), tested_dofs, intervals))


def _warm_alternatives(fit: Candidate, others: list[Candidate], warm: np.ndarray,
                       carried: np.ndarray | None, searched: np.ndarray, det: Detections,
                       model: KinematicModel, rig: Rig, params: FitParams, tolerance: float,
                       offsets: np.ndarray | None) -> list[Candidate]:
    """The previous image's posture (``warm[-1]``, of the warm starts (k, D)) refined on this
    image, where it lands in another minimum: within ``tolerance`` of the fit's objective
    (or better) and more than :data:`~core.ambiguity.DISTINCT_DEG` from the fit and every
    other alternative in some rotational DOF; and the previous image's alternatives
    (``carried``, (k, D) or None), reported only unless they tie with the fit.

    The previous posture is tried only where the attempt searched (``searched``, (D,) bool,
    :func:`fit_image`'s) and the fit left the warm starts' basin (moved more than
    :data:`~core.ambiguity.DISTINCT_DEG` from each of them; at 50-200 Hz most images do
    not, and nothing is refined). A part a warm start placed is those postures refined on
    this image already: at 50 Hz a leg moves 20-30° between images, so it left their basin,
    and refining ``warm[-1]`` again found its own fit. For a tree (``core.tree``), each
    searched part that moved is taken from ``warm[-1]`` on its own, the rest of the fit
    kept: one leg that jumped must not need every other leg to be as it was. At most the
    best two are kept.

    A carried alternative is tried wherever it differs from the fit: where the warm start
    carries a wrong minimum on and this image supports it as well as the right one, SA
    finds nothing lower, and the right posture was the previous image's alternative. The
    best one that lands within the tolerance is kept. The choice by continuity may take it
    only where it ties with the fit, within the tolerance's fixed floor
    (:func:`tolerance_readings`): offered wherever the tolerance reached, the candidates
    followed from image to image made smooth wrong paths that it took. Reported only at a
    tie, it left the choice no posture near the right neighbours', and the choice took a
    third minimum 16 px above the fit (docs/BENCH_SUBJECTS.md, stop 56).

    Each start is refined twice: on every projection, and without those that look hidden
    at the start itself (``core.treefit.refine_without_lost``). With a marker hidden from a
    camera, the first refinement pulls that marker onto a ghost or a neighbour's blob, and
    the start slides into the fit's minimum. The second is kept where it explains the other
    projections as well as the fit does (within ``tolerance``): the image cannot tell a
    hidden marker from one on a ghost. The choice by continuity may take it only where its
    whole objective is within ``tolerance`` of the fit's too; otherwise it is reported, not
    chosen (``Candidate.minimum`` False), as each extra candidate offered to that choice
    also lets it leave a right fit for a wrong neighbour.
    """
    rot = model.rotational

    def moved(dofs: np.ndarray) -> bool:
        return all(distinct(w[dofs], fit.dofs[dofs], rot[dofs]) for w in warm)

    parts = [np.arange(len(model.dofs))] if model.tree is None else [p.dofs for p in model.tree.parts]

    def spliced(source: np.ndarray, dofs: np.ndarray) -> np.ndarray:
        start = fit.dofs.copy()
        start[dofs] = source[dofs]
        return start

    starts = [spliced(warm[-1], dofs) for dofs in parts if searched[dofs].any() and moved(dofs)]
    followed = [a for a in (() if carried is None else carried) if distinct(a, fit.dofs, rot)]
    off = view_offsets(offsets, rig)
    found: list[Candidate] = []

    def keep(q: np.ndarray, error: float, objective: float, scores_as_well: bool,
             choosable_px: float) -> None:
        if scores_as_well and all(distinct(q, c.dofs, rot) for c in (fit, *others, *found)):
            found.append(Candidate(q, error, objective, objective <= fit.objective + choosable_px))

    def refine(start: np.ndarray, choosable_px: float) -> None:
        q, error, objective = refine_whole(start.copy(), det, model, rig, params, off)
        keep(q, error, objective, objective <= fit.objective + tolerance, choosable_px)
        if (without := refine_without_lost(start, det, model, rig, params, off)) is not None:
            q, error, objective, lost = without
            keep(q, error, objective, _seen_objective(q, lost, det, model, rig, params, off)
                 <= _seen_objective(fit.dofs, lost, det, model, rig, params, off) + tolerance,
                 choosable_px)

    for start in starts:
        refine(start, tolerance)
    found.sort(key=lambda c: c.objective)
    del found[2:]
    kept = len(found)
    tie = tolerance_readings(params, det, model, fit.error, len(model.dofs))[0]
    for start in followed:
        refine(start, tie)
    return found[:kept] + sorted(found[kept:], key=lambda c: c.objective)[:1]


def seen_from_after(fit: ImageFit, after: np.ndarray, det: Detections, *, model: KinematicModel,
                    rig: Rig, params: FitParams, offsets: np.ndarray | None = None) -> ImageFit:
    """``fit`` offered ``after`` (k, D), postures the next images predict for it
    (``core.sequence.fit_chunk``), as more starts: each that differs from the fit (more than
    :data:`~core.ambiguity.DISTINCT_DEG` in some angle) is refined on this image, whole, and
    the lowest is kept where it lands in a lower minimum (by more than :data:`TIE_PX`),
    distinct from the fit; the old fit and its alternatives stay alternatives while within
    the tolerance of it (:func:`_still_alternatives`), and without any, the new posture is
    given its witness as an attempt's is (:func:`_witnessed`). ``fit`` itself otherwise,
    reporting the refined start as its alternative (:func:`_reported_from_after`) where it
    lands no lower but within the tolerance and the fit has no distinct alternative: a fit
    with glints on the limbs (a random tree, two cameras, three glints per view) stayed
    ``ok`` 11° off with none, while the next image's posture, refined on it, landed 3° from
    the truth 0.36 px above it (docs/BENCH_SUBJECTS.md, stop 56).

    Why: a chunk's warm starts run forward only. Where SA ends in a wrong minimum that the
    image supports almost as well as the right one, the next images' warm starts carry it
    on, until one image's SA finds the right one again; the images before it keep the
    wrong posture. The stick insect leg (seed 0, a leg beyond a roi) kept images 32-35
    26-30° off that way, image 35 ``ok`` at 0.66 px with no alternative while its truth
    scores 0.34 px; image 36 was right (docs/BENCH_SUBJECTS.md, stop 54)."""
    if fit.status is Status.NO_DETECTIONS:
        return fit
    starts = [a for a in after if np.all(np.isfinite(a)) and distinct(a, fit.dofs, model.rotational)]
    if not starts:
        return fit
    off = view_offsets(offsets, rig)
    q, error, objective = min((refine_whole(start.copy(), det, model, rig, params, off) for start in starts),
                              key=lambda refined: refined[2])
    rot = model.rotational
    if not distinct(q, fit.dofs, rot):
        return fit
    if not objective < fit.objective - TIE_PX:
        return _reported_from_after(fit, Candidate(q, error, objective, minimum=False), det, model, params)
    best = Candidate(q, error, objective)
    charged, outside = _unshown(q, det, model, rig, params, offsets)
    kept = _still_alternatives(best, (), fit, det, model, params, _seen_error(error, outside))
    return replace(fit, dofs=q, error=error, objective=objective,
                   status=image_status(error, fit.detections, len(model.markers), params),
                   alternatives=_witnessed(best, kept, det, model, rig, params, offsets), settled=False,
                   charged=charged, outside=outside)


def _reported_from_after(fit: ImageFit, other: Candidate, det: Detections, model: KinematicModel,
                         params: FitParams) -> ImageFit:
    """``fit`` with ``other``, a posture the next images predict refined on this image and
    landing no lower, reported as its alternative (``Candidate.minimum`` False) where it lies
    within :func:`alternative_tolerance` of the fit and the fit has no alternative distinct
    from it; else ``fit``."""
    if math.isfinite(fit.alternative_deg(model.rotational)):
        return fit
    seen = _seen_error(fit.error, fit.outside)
    if other.objective > fit.objective + alternative_tolerance(params, det, model, seen, len(model.dofs)):
        return fit
    return replace(fit, alternatives=(*fit.alternatives, other))


def _still_alternatives(best: Candidate, alternatives: tuple[Candidate, ...], previous: ImageFit,
                        det: Detections, model: KinematicModel, params: FitParams,
                        seen_error: float) -> tuple[Candidate, ...]:
    """The kept posture of a re-analysed image, and its alternatives, where a re-analysis
    found a lower minimum ``best``, distinct from it and from its ``alternatives``: those
    that are minima while still within :func:`alternative_tolerance` of it (read from
    ``seen_error``, its error without its projections beyond the edges, :func:`_seen_error`), those reported
    only (``Candidate.minimum`` False) where ``best`` is the kept posture's own minimum
    found again.

    A re-analysis that finds a lower minimum would otherwise drop the first attempt's
    candidates: where the image supports both postures about as well (a marker hidden from
    one camera, a Fig. 9 flip), the right one, often the first attempt's warm-started fit or
    its alternative, is then lost to the choice by continuity. A reported alternative (the
    previous image's posture refined without a marker hidden here) belongs to the minimum it
    was found beside: an attempt ending a hair lower in that same, wrong, minimum must not
    leave the image `ok` with no alternative.
    """
    tolerance = alternative_tolerance(params, det, model, seen_error, len(model.dofs))
    rot = model.rotational
    again = not distinct(best.dofs, previous.dofs, rot)
    kept: list[Candidate] = []
    for c in (previous.as_candidate(), *previous.alternatives):
        still = c.objective <= best.objective + tolerance if c.minimum else again
        if still and all(distinct(c.dofs, o.dofs, rot) for o in (best, *alternatives, *kept)):
            kept.append(c)
    return tuple(kept)


def _seen_objective(q: np.ndarray, lost: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                    params: FitParams, off: np.ndarray) -> float:
    """The objective (pixels) of a whole posture ``q`` (D,) without the projections ``lost``
    (V, M) bool marks (``core.part_objective.part_objective`` of the whole model)."""
    return part_objective(q, model.arrays, det.kernel_points, det.start, lost, rig, params, off)


@one_blas_thread
def reanalyse_image(
    detections: Detections,
    previous: ImageFit,
    *,
    model: KinematicModel,
    rig: Rig,
    histograms: Histograms,
    params: FitParams,
    seed: int,
    offsets: np.ndarray | None = None,
    typical: float = math.nan,
) -> ImageFit:
    """One more attempt on an image :func:`needs_reanalysis` picks (paper §3.2), keeping the
    better posture (``typical``: the sequence's ``core.sequence.typical_objective``).

    The attempt starts from a posture drawn from ``histograms`` (the merged
    constraints), so that it does not retrace the first attempt's path, and
    uses the stream :func:`image_stream` ``(seed, sample, attempts + 1)``.
    The kept attempt brings its alternatives along; where the attempt finds a lower minimum,
    the first posture and its alternatives stay alternatives while within the tolerance
    (:func:`_still_alternatives`).

    Where the attempt ends in the kept posture's minimum (within :data:`~core.ambiguity.DISTINCT_DEG` in
    every angle, its objective not lower by ε, SA's stop, or more), the fit is ``settled``
    and :func:`needs_reanalysis` asks for no more: two searches from unrelated starts (the
    first from the histograms' means or the previous image's posture, this one drawn)
    agree, and the image's error is what its markers leave in that minimum (sliding skin
    markers, a marker the model lacks), which more attempts would find again. An attempt
    that finds a lower minimum, or a posture more than :data:`~core.ambiguity.DISTINCT_DEG` away, leaves it
    unsettled: the search goes on, as the paper's re-analysis.

    Where the kept posture has projections beyond their views' edges, SA reads the edges too
    (``FitParams.search_edges``). A first attempt's SA reads plain Eq. 5 there, so that a
    limb out of the frame is never lost off it; but it charges such a marker its distance to
    a blob inside, and a spider's leg that had walked out of one of two cameras' frames
    was pulled back in, 60-80° off and 40 px above the truth, in every attempt
    (docs/BENCH_SUBJECTS.md, stop 53).

    A tree (``model.tree``) is re-analysed part by part given the kept posture
    (``core.treefit.refit_tree``, each part's SA stopping as low as its kept posture, and a
    part no worse than the ``typical`` image's by what its residual can tell apart not
    searched again): a
    whole attempt from a drawn start searches every part cold at once, and one part landing
    in a worse minimum made it worse than the kept posture, whose warm-started parts
    agreed, in almost every image. It is settled when
    every part is, or when the attempt is not lower than the kept posture: each part was
    searched again from a drawn start and kept its lower posture, and the whole objective
    still prefers the kept one, so what the parts found lower was blobs another part
    explains, which another draw would find again.
    """
    attempt = previous.attempts + 1
    if not needs_reanalysis(previous, model, params, typical):
        return previous
    tree = model.tree is not None
    searched = replace(params, search_edges=previous.outside[0] > 0)
    best, alternatives, its, settled = _attempt(
        detections, model, rig, search_space(model, histograms), searched,
        image_stream(seed, previous.sample, attempt), True, offsets, flip_geometry(model, rig),
        keep=previous.dofs if tree else None, typical=typical,
    )
    if not tree:
        settled = (best.objective > previous.objective - params.anneal.eps
                   and not distinct(best.dofs, previous.dofs, model.rotational))
    else:
        settled = settled or not best.objective < previous.objective
    if not best.objective < previous.objective:
        best, charged, outside = previous.as_candidate(), previous.charged, previous.outside
        alternatives = previous.alternatives
    else:
        charged, outside = _unshown(best.dofs, detections, model, rig, params, offsets)
        kept = _still_alternatives(best, alternatives, previous, detections, model, params,
                                   _seen_error(best.error, outside))
        alternatives = tuple(sorted(alternatives + kept, key=lambda c: c.objective))
    status = image_status(best.error, previous.detections, len(model.markers), params)
    return ImageFit(previous.sample, best.dofs, best.error, best.objective, attempt, status,
                    previous.iterations + its, previous.detections, alternatives, settled, charged,
                    outside)


def needs_reanalysis(fit: ImageFit, model: KinematicModel, params: FitParams,
                     typical: float = math.nan) -> bool:
    """True while an image has attempts left, is not ``settled`` (:func:`reanalyse_image`)
    and is over the error threshold (paper §3.2), or its objective is an outlier: above
    ``params.outlier_factor`` times ``typical`` (the sequence's
    ``core.sequence.typical_objective``) and above the level where ``model``'s search stops
    in the image's views (``core.treefit.search_floor``: ε for a chain, the smallest of
    its parts' ε for a tree). The typical objective leaves out what markers the images do
    not show cost (``ImageFit.charged``): a hidden marker costs the empty-view penalty in
    every minimum, so where most images hide one, the median is that penalty, and a wrong
    minimum a few pixels above the right one hides under three times it. The image's own
    objective is compared whole: a wrong posture that leaves a marker off every blob looks
    just like a hidden one. Only what its projections outside their views' regions
    (``ImageFit.outside``) cost is left out, as it is from the threshold's test: no
    detection can lie there, whatever the posture.

    The paper's 10 px threshold was "clearly larger than the expected analysis
    result" (2.9 px); clean footage now fits at ~0.1 px, so a local minimum at
    5-9 px is far from typical yet under the threshold. Outliers are re-analysed
    like over-threshold images; their status still says only whether the error
    is over the threshold. A tree's parts each stop at their own ε, so a whole
    animal that fits most images far below it would otherwise send every image
    that stops near it to attempts that stop there again.

    Three times, not ten: on a whole animal a wrong leg adds little to the mean error
    per projection, and footage whose every image fits a few tenths of a pixel off the
    model (motion blur, sliding skin) leaves one that scores 2.5-4 times the typical
    objective under the threshold: a spider filmed with motion blur kept two legs 21-38°
    off, `ok`, without an alternative (docs/BENCH_SUBJECTS.md, stop 51).
    """
    if fit.attempts >= params.max_attempts or fit.status is Status.NO_DETECTIONS or fit.settled:
        return False
    if fit.status is Status.OVER_THRESHOLD and not _over_by_outside(fit, len(model.markers), params):
        return True
    views_seen = sum(1 for c in fit.detections if c > 0)
    limit = max(search_floor(model, params, views_seen), params.outlier_factor * typical)
    seen = fit.objective - fit.charged_beyond(params)
    return params.outlier_factor > 0 and math.isfinite(limit) and seen > limit


def _outside(value: Sequence[float]) -> tuple[int, float]:
    count, px = value
    return int(count), float(px)


def _json_float(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def _float(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _float_array(values: Sequence[float | None]) -> np.ndarray:
    return np.array([_float(v) for v in values], dtype=np.float64)


def _over_by_outside(fit: ImageFit, n_markers: int, params: FitParams) -> bool:
    """Whether only projections outside their views' regions (``ImageFit.outside``) put
    ``fit`` over the threshold: the rest are within it per projection."""
    count, px = fit.outside
    return count > 0 and fit.error - px <= params.error_threshold_px * (fit.compared(n_markers) - count)


def image_status(error: float, detections: tuple[int, ...], n_markers: int, params: FitParams) -> Status:
    """ok or over_threshold, from the Eq. 5 ``error`` (px) per compared marker projection
    (``detections``: points per view)."""
    limit = params.error_threshold_px * _compared(detections, n_markers)
    return Status.OK if error <= limit else Status.OVER_THRESHOLD


def _compared(detections: tuple[int, ...], n_markers: int) -> int:
    return n_markers * sum(1 for c in detections if c > 0)
