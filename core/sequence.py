"""A sequence's steps: chunks → merge and pick → re-analysis → finish, each defined once.

``mocap fit`` (:func:`fit_sequence`, in this process or a pool of processes) and the
service's workers (``worker.orchestration``, one task per chunk and per attempt) call
these same functions; the workers add only the database, the queue and idempotence.

1. :func:`plan_chunks` splits the images into contiguous chunks (``core.pipeline.plan``
   adds the root tracking of a video job).
2. :func:`fit_chunk` fits a chunk's images once each (``core.fit.first_attempt``), starting
   from the given histograms and updating a working copy after every image whose error is
   within the threshold (Eq. 4), then offers each image whose fit departs from what its
   next images predict those postures, last to first (``core.fit.seen_from_after``). It
   returns the fits and the *observed* histograms of its images alone.
3. :func:`plan_reanalysis`: the prior merged with every chunk's observed histograms
   (count-weighted; exactly the sequential Eq. 4 update when there is one chunk), the
   sequence's :func:`typical_objective`, and the images ``core.fit.needs_reanalysis``
   picks (over the threshold, or far above the typical objective), with their next attempt.
4. Each picked image is re-analysed (paper §3.2) with the merged histograms as constraints,
   one ``core.fit.reanalyse_image`` attempt at a time, up to ``max_attempts``, keeping its
   best posture; the attempts start from postures drawn from the histograms.
5. :func:`finish_sequence`: each image's posture chosen among its alternatives by
   continuity, and the prior updated by the final posture of every image within the
   threshold. ``core.pipeline.outputs`` then gives the result files' contents.

An image's random stream depends only on ``(seed, sample, attempt)``, a chunk's first
image starts cold and its last is offered nothing from after it, so any chunk can be fitted
by any worker, in any order, and give the same postures as a single process fitting the
same chunks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from itertools import pairwise

import numpy as np

from core.ambiguity import angle_gaps, choose_candidates
from core.ceilings import warm_ceilings
from core.error import Detections, view_offsets
from core.fit import (
    FitParams,
    ImageFit,
    Status,
    first_attempt,
    flip_geometry,
    image_status,
    needs_reanalysis,
    reanalyse_image,
    seen_from_after,
)
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig
from core.threads import one_blas_thread
from core.undetermined import UNDETERMINED_DEG

__all__ = [
    "ChunkResult",
    "Reanalysis",
    "SequenceResult",
    "finish_sequence",
    "fit_chunk",
    "fit_sequence",
    "images_to_reanalyse",
    "plan_chunks",
    "plan_reanalysis",
    "typical_objective",
]

MAX_CARRIED = 2  # alternatives of an image followed on to the next, at most
CYCLE_HISTORY = 64  # images searched for the previous cycle's matching posture
CYCLE_MIN_IMAGES = 4  # fitted images before the cycle is searched (2 steps besides the last one)


@dataclass(frozen=True)
class ChunkResult:
    """Fits of a chunk, in sample order, and the histograms of its accepted angles alone."""

    fits: list[ImageFit]
    observed: Histograms


@dataclass(frozen=True)
class Reanalysis:
    """What step 3 decided once every chunk is fitted.

    histograms : the prior merged with every chunk's observations: the re-analyses' constraints.
    typical : the sequence's :func:`typical_objective` of the first attempts.
    images : (sample, next attempt) of every image to re-analyse, in sample order.
    """

    histograms: Histograms
    typical: float
    images: list[tuple[int, int]]


@dataclass(frozen=True)
class SequenceResult:
    """Fits of a sequence in sample order, and the prior updated by every accepted image.

    observed : the histograms of the accepted images alone (``histograms`` is the
        prior merged with it), to fold a job into an archive that has moved on.
    """

    fits: list[ImageFit]
    histograms: Histograms
    observed: Histograms


def plan_chunks(n_images: int, chunk_size: int | None) -> list[tuple[int, int]]:
    """Step 1: contiguous ``[first, last)`` sample ranges covering ``n_images``, as few as
    hold at most ``chunk_size`` images each, of sizes that differ by one at most; one chunk
    for ``None``.

    Even sizes because chunks run in parallel: 60 images in chunks of at most 50 are two of
    30, which two workers finish together, not 50 and 10.

    >>> plan_chunks(60, 50), plan_chunks(7, 3), plan_chunks(4, None)
    ([(0, 30), (30, 60)], [(0, 2), (2, 4), (4, 7)], [(0, 4)])
    """
    if chunk_size is not None and (isinstance(chunk_size, bool) or chunk_size < 1):
        raise ValueError(f"chunk_size must be at least 1, got {chunk_size!r}")
    count = 1 if chunk_size is None else -(-n_images // chunk_size)
    bounds = [k * n_images // count for k in range(count + 1)] if n_images else []
    return list(pairwise(bounds))


@one_blas_thread
def fit_chunk(
    images: Iterable[Detections],
    *,
    model: KinematicModel,
    rig: Rig,
    histograms: Histograms,
    params: FitParams,
    seed: int,
    first_sample: int = 0,
    offsets: Iterable[np.ndarray | None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    progress: Callable[[ImageFit], None] | None = None,
) -> ChunkResult:
    """Step 2: fit a contiguous run of images once each.

    Parameters
    ----------
    images : iterable of Detections, samples ``first_sample, first_sample + 1, …``.
    histograms : the constraints at the start of the chunk; not modified.
    seed : the job's seed; image ``s`` uses ``core.fit.image_stream`` ``(seed, s, 1)``.
        Each image after the chunk's first starts from the previous images' postures
        (warm starts, :func:`_warm_starts`, each part's taken up to its level in the
        previous image, :func:`_ceilings`, computed only where a part's warm start misses
        twice its ε) and tries the previous one as an alternative;
        the chunk's first image starts cold. Then each image but the last whose fit departs
        from what its next images predict is offered those postures, last image first
        (:func:`_offer_backward`), and keeps one where, refined, it lands in a lower minimum:
        the warm starts run forward only, and carry a wrong minimum on until an image's SA
        leaves it. A chunk's fits depend on its images and nothing outside them: fitted
        anywhere, the same chunks give the same fits.
    offsets : optional per-image (V, 2) view offsets (root tracking), same length as images.
    should_stop : checked between images; returning True ends the chunk early (cancel).
    progress : called with every finished image.
    """
    working = histograms.copy()
    observed = Histograms.empty(model, bins=histograms.bins)
    rot = model.rotational
    geometry = flip_geometry(model, rig)
    offset_iter = iter(offsets) if offsets is not None else None
    fits: list[ImageFit] = []
    seen: list[tuple[Detections, np.ndarray | None]] = []
    ceilings: Callable[[], dict[str, float]] | None = None
    for k, det in enumerate(images):
        if should_stop is not None and should_stop():
            break
        off = next(offset_iter) if offset_iter is not None else None
        seen.append((det, off))
        warm = _warm_starts(fits, model)
        fit = first_attempt(
            det, first_sample + k, model=model, rig=rig, histograms=working, params=params,
            seed=seed, geometry=geometry, offsets=off, warm=warm,
            ceilings=ceilings if warm is not None else None,
            carried=_carried(fits, model) if warm is not None else None,
            previous=fits[-1].objective if warm is not None else math.nan,
        )
        if model.tree is not None:  # used only after a posture (``warm`` is None without one)
            ceilings = partial(_ceilings, fit, det, model, rig, params, off)
        if fit.status is Status.OK:
            working.update(fit.dofs[rot])
        fits.append(fit)
        if progress is not None:
            progress(fit)
    _offer_backward(fits, seen, model, rig, params)
    for fit in fits:
        if fit.status is Status.OK:
            observed.update(fit.dofs[rot])
    return ChunkResult(fits, observed)


def _offer_backward(fits: list[ImageFit], seen: list[tuple[Detections, np.ndarray | None]],
                    model: KinematicModel, rig: Rig, params: FitParams) -> None:
    """Offer each of a chunk's ``fits`` but the last, last first, the postures its next images
    predict (:func:`_backward_starts`; ``core.fit.seen_from_after``), in place, where the fit
    does not continue their movement: more than ``core.undetermined.UNDETERMINED_DEG`` from
    the first of those postures in some angle. ``seen`` holds each image's detections and
    view offsets. Last first, so that a right posture found again is carried back through
    a run of images a wrong minimum held.

    Why only there: a wrong minimum lies 10° or more from the right one (a Fig. 9 flip, a
    leg swapped or folded), and the right posture continues the movement. Each offer
    refines one or two whole postures, which is a large share of a fit that walks with its
    next images, as a clean walking hexapod does in every image. The objective is not
    compared with the next image's: under sliding skin markers a wrong fit need not score
    above its neighbour. What each rule cost and saved is in docs/BENCH_SUBJECTS.md, stop 54."""
    rot = model.rotational
    for k in range(len(fits) - 2, -1, -1):
        starts = _backward_starts(fits[k + 1:k + 3], model)
        if angle_gaps(fits[k].dofs, starts[0])[rot].max(initial=0.0) > UNDETERMINED_DEG:
            det, off = seen[k]
            fits[k] = seen_from_after(fits[k], starts, det, model=model, rig=rig, params=params, offsets=off)


def _backward_starts(after: list[ImageFit], model: KinematicModel) -> np.ndarray:
    """(k, D): what the next images ``after`` (the next, then the one after it, if any)
    predict for the image before them: the next one moved back by its step from the one
    after it (constant velocity, within the ranges), then the next one as it is.

    Both, as the forward warm starts: a leg that slows or turns is overshot by the step (a
    free fly with two cameras, image 26: the step's start, 7.7° off, refined 44 px above
    the next posture's, 12.8° off, which found the truth).

    >>> from core.examples import LOCUST
    >>> from core.model import KinematicModel
    >>> model = KinematicModel.from_xml(LOCUST / "model.xml")
    >>> fit = ImageFit(1, model.lower + 12.0, 0.1, 0.1, 1, Status.OK, 1, (4, 4))
    >>> after = replace(fit, sample=2, dofs=model.lower + 16.0)
    >>> (_backward_starts([fit, after], model)[:, 0] - model.lower[0]).tolist()
    [8.0, 12.0]
    >>> _backward_starts([fit], model).shape
    (1, 5)
    """
    last = after[0].dofs
    if len(after) < 2 or not np.all(np.isfinite(after[1].dofs)):
        return last[None]
    return np.vstack([_stepped(last, after[1].dofs, model), last])


def _warm_starts(fits: list[ImageFit], model: KinematicModel) -> np.ndarray | None:
    """Warm starts of the image after ``fits`` (the chunk's so far), (k, D), best guess first:
    the last posture moved on by its last step (constant velocity, within the ranges), then,
    from the chunk's fourth image on, each part moved on by the step its previous cycle took
    from the same posture (:func:`_next_in_cycle`), then the last posture itself (last:
    ``core.fit`` reads it as the previous image's posture); None at a chunk's first image
    and after an image without a posture, so that a chunk's fits depend on nothing before
    it.

    >>> from core.examples import LOCUST
    >>> from core.model import KinematicModel
    >>> model = KinematicModel.from_xml(LOCUST / "model.xml")
    >>> fit = ImageFit(0, model.lower + 10.0, 0.1, 0.1, 1, Status.OK, 1, (4, 4))
    >>> _warm_starts([], model) is None, _warm_starts([fit], model).shape
    (True, (1, 5))
    >>> moved = replace(fit, sample=1, dofs=model.lower + 12.0)
    >>> (_warm_starts([fit, moved], model)[:, 0] - model.lower[0]).tolist()
    [14.0, 12.0]
    """
    if not fits or not np.all(np.isfinite(last := fits[-1].dofs)):
        return None
    if len(fits) < 2 or not np.all(np.isfinite(before := fits[-2].dofs)):
        return last[None]
    rows = [_stepped(last, before, model), last]
    if (cycle := _next_in_cycle(fits, model)) is not None:
        rows.insert(1, cycle)
    return np.vstack(rows)


def _stepped(last: np.ndarray, other: np.ndarray, model: KinematicModel) -> np.ndarray:
    """(D,) ``last`` moved on by its step from ``other`` (constant velocity), within the
    model's ranges: the image after ``last`` when ``other`` came before it, the image
    before when ``other`` came after."""
    return np.clip(2.0 * last - other, model.lower, model.upper)


def _next_in_cycle(fits: list[ImageFit], model: KinematicModel) -> np.ndarray | None:
    """(D,) the last posture moved on, part by part (``model.tree``'s parts, else the whole
    posture), by the step that followed the earlier image whose posture of the part lies
    nearest the last image's (within the ranges); None before :data:`CYCLE_MIN_IMAGES`
    images or without such an image.

    Why: legs cycle. Where a leg moves beyond the reach of the last step's extrapolation
    (a fly's 6-11 steps/s filmed at 50 Hz move a tibia 20-30° per image), its previous
    cycle has passed the same posture and shows the step that comes next."""
    history = np.array([f.dofs for f in fits[-CYCLE_HISTORY:]])
    if len(history) < CYCLE_MIN_IMAGES:
        return None
    last = history[-1]
    step = history[1:-1] - history[:-2]  # (h, D): from each earlier image to the one after it
    gap = history[:-2] - last
    rot = model.rotational
    gap[:, rot] = (gap[:, rot] + 180.0) % 360.0 - 180.0
    step[:, rot] = (step[:, rot] + 180.0) % 360.0 - 180.0
    known = np.all(np.isfinite(step), axis=1) & np.all(np.isfinite(gap), axis=1)
    if not known.any():
        return None
    parts = [p.dofs for p in model.tree.parts] if model.tree is not None else [np.arange(len(last))]
    out = last.copy()
    for dofs in parts:
        far = np.where(known, np.einsum("hd,hd->h", gap[:, dofs], gap[:, dofs]), np.inf)
        out[dofs] += step[int(np.argmin(far)), dofs]
    return np.clip(out, model.lower, model.upper)


def _carried(fits: list[ImageFit], model: KinematicModel) -> np.ndarray | None:
    """The alternatives of the last of ``fits`` that are minima, best first, then, in a
    model with DOFs its markers determine in no posture (``model.identifiability``), its
    witnesses of those DOFs; at most :data:`MAX_CARRIED`, (k, D); None without any.

    Refined on the next image (``core.fit.first_attempt``), they give it an alternative
    where a warm start carried a wrong minimum on that both images support as well as the
    right one: a rat whose ankle and toe no camera sees fits a leg folded onto other blobs
    lower than the truth, which is the previous image's alternative, and the next image's
    warm start is the folded leg (docs/BENCH_SUBJECTS.md).

    A witness (``Candidate.minimum`` False) lies in a flat valley that such a model has in
    every image. Where a fusion moves the fit off it into a separate, higher minimum, the
    witness search from the fit finds nothing within the tolerance, and the previous
    witness, refined, is the image's alternative (docs/BENCH_SUBJECTS.md, random trees).
    Not in other models: there a witness carried on keeps images flagged that have nothing
    undetermined.
    """
    if not fits:
        return None
    undetermined = bool(model.identifiability.undetermined)
    alternatives = [a for a in fits[-1].alternatives if a.minimum or undetermined]
    carried = [a.dofs for a in sorted(alternatives, key=lambda a: not a.minimum)][:MAX_CARRIED]
    return np.array(carried) if carried else None


def _ceilings(fit: ImageFit, det: Detections, model: KinematicModel, rig: Rig, params: FitParams,
              offsets: np.ndarray | None) -> dict[str, float]:
    """Where the next image's warm starts stand in for SA, per part: the lowest
    ``core.ceilings.warm_ceilings`` on ``det`` (``offsets``: the image's (V, 2) view offsets,
    optional) of ``fit`` and of its alternatives.

    The fit is the candidate of lowest *whole* objective; where an alternative fits a part
    better (a posture the whole objective prefers because a marker of that part counts as
    lost, say), the part's own level is the alternative's, and a warm start carrying the
    fit's posture of that part forward must beat it, or the part is searched again. NaN
    levels (no ceiling) count only where every candidate has one."""
    off = view_offsets(offsets, rig)
    levels = [warm_ceilings(c.dofs, det, model, rig, params, off)
              for c in (fit, *fit.alternatives)]
    return {name: float(np.fmin.reduce([level[name] for level in levels])) for name in levels[0]}


def typical_objective(fits: Iterable[ImageFit]) -> float:
    """The median objective of a sequence's fitted images (NaN without any), each without
    what markers its image does not show cost (``ImageFit.charged``): what a good fit of this
    footage scores, for ``core.fit.needs_reanalysis``."""
    values = [f.objective - f.charged for f in fits if f.status is not Status.NO_DETECTIONS]
    return float(np.median(values)) if values else math.nan


def images_to_reanalyse(fits: Iterable[ImageFit], model: KinematicModel, params: FitParams,
                        typical: float) -> list[tuple[int, int]]:
    """(sample, next attempt) of every fit of ``model`` ``core.fit.needs_reanalysis`` picks,
    in the order given."""
    return [(f.sample, f.attempts + 1) for f in fits if needs_reanalysis(f, model, params, typical)]


def plan_reanalysis(prior: Histograms, observed: Iterable[Histograms], fits: Sequence[ImageFit],
                    model: KinematicModel, params: FitParams) -> Reanalysis:
    """Step 3, once every chunk is fitted: ``observed`` (each chunk's) merged into ``prior`` by
    counts, the typical objective of ``fits`` (the chunks' first attempts of ``model``, in
    sample order) and the images to re-analyse."""
    typical = typical_objective(fits)
    return Reanalysis(prior.merge(*observed), typical,
                      images_to_reanalyse(fits, model, params, typical))


def finish_sequence(
    prior: Histograms, fits: Sequence[ImageFit], *, model: KinematicModel, params: FitParams
) -> SequenceResult:
    """Step 5: the fits in sample order and the prior updated by every image within the threshold.

    With ``params.choose_by_continuity``, each image's posture is first chosen
    among its alternatives (``core.ambiguity.choose_candidates``). Eq. 4 counts
    do not depend on the order of the measurements, so the histograms equal
    updating the prior image by image with the final postures.
    """
    ordered = sorted(fits, key=lambda f: f.sample)
    if params.choose_by_continuity:
        ordered = _chosen_by_continuity(ordered, len(model.markers), params)
    observed = Histograms.empty(model, bins=prior.bins)
    for fit in ordered:
        if fit.status is Status.OK:
            observed.update(fit.dofs[model.rotational])
    return SequenceResult(ordered, prior.merge(observed), observed)


def _chosen_by_continuity(fits: list[ImageFit], n_markers: int, params: FitParams) -> list[ImageFit]:
    candidates = [
        [] if f.status is Status.NO_DETECTIONS
        else [f.as_candidate(), *f.alternatives]
        for f in fits
    ]
    minima = [[i for i, c in enumerate(cands) if c.minimum] for cands in candidates]
    chosen_minima = choose_candidates(
        [[cands[i] for i in m] for cands, m in zip(candidates, minima, strict=True)],
        [f.charged_beyond(params) for f in fits])
    out = []
    for fit, cands, m, j in zip(fits, candidates, minima, chosen_minima, strict=True):
        k = m[j] if m else 0
        if k:
            chosen = cands[k]
            fit = replace(fit, dofs=chosen.dofs, error=chosen.error, objective=chosen.objective,
                          status=image_status(chosen.error, fit.detections, n_markers, params),
                          alternatives=tuple(c for i, c in enumerate(cands) if i != k))
        out.append(fit)
    return out


def fit_sequence(
    images: Sequence[Detections],
    *,
    model: KinematicModel,
    rig: Rig,
    histograms: Histograms,
    params: FitParams,
    seed: int,
    chunk_size: int | None = None,
    offsets: Sequence[np.ndarray | None] | None = None,
    progress: Callable[[ImageFit], None] | None = None,
    map_chunks: Callable[..., Iterable[ChunkResult]] = map,
) -> SequenceResult:
    """Fit every image of a sequence: the module's five steps, in this process or, through
    ``map_chunks``, in others.

    Parameters
    ----------
    images : sequence of Detections; slicing ``images[a:b]`` may return any iterable
        (a video source decodes that range lazily), ``images[i]`` one image.
    chunk_size : images per chunk; ``None`` fits the sequence as one chunk (histograms
        adapt over the whole sequence, as in the paper). A chunked fit reproduces exactly
        what workers fitting those chunks in parallel produce.
    progress : called with every image fitted in this process.
    map_chunks : ``map`` or an executor's ``map``, to fit chunks, then re-analyse images, in
        other processes.
    """
    n = len(images)
    if offsets is not None and len(offsets) != n:
        raise ValueError(f"offsets has {len(offsets)} entries for {n} images")
    run = partial(_fit_range, images, model, rig, histograms, params, seed, offsets, progress)
    chunks = list(map_chunks(run, plan_chunks(n, chunk_size)))
    fits = [f for c in chunks for f in c.fits]  # fits[s] is sample s: the chunks cover 0..n-1
    todo = plan_reanalysis(histograms, [c.observed for c in chunks], fits, model, params)
    samples = [sample for sample, _ in todo.images]
    redo = partial(_attempts_while_needed, images, model, rig, todo.histograms, params, seed,
                   offsets, todo.typical)
    for sample, fit in zip(samples, map_chunks(redo, [fits[s] for s in samples]), strict=True):
        fits[sample] = fit
    return finish_sequence(histograms, fits, model=model, params=params)


def _attempts_while_needed(images, model, rig, histograms, params, seed, offsets, typical,
                           fit) -> ImageFit:
    """Step 4 for one image of :func:`fit_sequence`: attempts while it needs them (a
    module-level function, so that the processes fitting the chunks share the re-analyses;
    an image's attempts depend on nothing but itself and ``histograms``)."""
    det = images[fit.sample]
    while needs_reanalysis(fit, model, params, typical):
        fit = reanalyse_image(
            det, fit, model=model, rig=rig, histograms=histograms, params=params, seed=seed,
            offsets=None if offsets is None else offsets[fit.sample], typical=typical,
        )
    return fit


def _fit_range(images, model, rig, histograms, params, seed, offsets, progress, bounds) -> ChunkResult:
    """One chunk of :func:`fit_sequence` (a module-level function, so processes can run it)."""
    a, b = bounds
    return fit_chunk(
        images[a:b], model=model, rig=rig, histograms=histograms, params=params, seed=seed,
        first_sample=a, offsets=None if offsets is None else offsets[a:b], progress=progress,
    )
