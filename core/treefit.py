"""One attempt on one image of a tree-shaped model, part by part (``core.tree``).

The parts are fitted in the tree's order, each by the paper's SA
(``core._kernels.fit_attempt``) over its own DOFs and markers with its base where the
parts fitted before it put it (the root's trunk first; a branch's own trunk before its
sub-branches); then the whole posture is refined jointly. Each part's SA stops at its own
ε, 0.25 px a marker projection by default (``core.part_objective``, which poses and scores a
part for every module of this fit).

Branches (every part with a base, a branch's own trunk too) compete for blobs: after the
first pass, each branch in a conflict (a blob that markers of two branches claim) is fitted
again without the blobs the other branches claim, and kept where that lowers the two-sided
error (``core.claims``, which says why).

A root trunk whose own markers are left unexplained after the first pass (hidden, or on
a blob a branch claims) is refined again on every marker of the model, the branches held
rigid (:func:`_trunk_by_whole`): its hidden markers would otherwise take limb blobs, and its
own objective prefers that wrong pose to the right one. Where it moves to another minimum
the branches are refitted given it, kept where the whole objective is lower.

Within a chunk, each part first tries the previous image's posture, refined, and runs SA
only where that does not stand in for it (``core.warm_start``; under sliding skin markers,
the ceiling it is held to, ``core.ceilings``); when every part came from a warm start the
joint refinement takes :data:`WARM_JOINT_STEPS` steps: at 50-200 Hz most parts of most
images skip SA (figures in docs/BENCH_SUBJECTS.md). Depth flips are searched branch by branch
(:func:`tree_flip_alternatives`). A part that SA leaves above its ε (with two or more
views) tries one more start, triangulated from the blobs (:func:`epipolar_start`,
``core.triangulate``), refined like a warm start and kept where it ends lower: a branch
posed onto the candidates within its reach, the root's trunk onto three candidates that
lie as its markers do (a free trunk searched from the middle of its translation ranges
can end on the wrong blobs, and every branch then hangs from the wrong place). With two
views every branch tries it, and every SA run's minimum of it and its warm start, kept where
it lowers the two-sided error (:func:`_two_view_starts`): there a leg on the wrong blobs can
explain all it projects onto, and the run SA ranks lowest can be one.

This module orchestrates; the rules it applies live in the modules below it, lowest
first: ``core.part_objective`` (a part posed and scored, its ε), ``core.claims`` (branches
competing for blobs), ``core.ceilings`` (a part's level and ceiling, the projections that
look hidden) and ``core.warm_start`` (when the previous image's posture stands in for SA).
None of them imports this module.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from core import _kernels
from core.ambiguity import (
    MAX_ALTERNATIVES,
    MAX_FLIP_REFINES,
    Candidate,
    FlipGeometry,
    distinct,
    flip_alternatives,
    flip_masks,
)
from core.anneal import kernel_params
from core.ceilings import (
    left_out_with_lost,
    missed_by_a_slide,
    typical_ceilings,
    under_ceiling,
)
from core.claims import (
    CLAIM_PX,
    claimed,
    claiming_at,
    claims_of,
    contested_projections,
    explained_blobs,
    reaches,
    shared_projections,
    subset,
    two_sided_error,
)
from core.epipolar_start import branch_start, trunk_start
from core.error import Detections, view_offsets
from core.model import KinematicModel
from core.part_objective import (
    base_frame,
    kernel_image,
    outside,
    part_eps,
    part_objective,
    seen_views,
    whole_image,
    world_frames,
)
from core.rig import Rig
from core.tree import Part, Tree, _subtrees
from core.triangulate import Candidates, triangulate
from core.warm_start import (
    WARM_EPS_FACTOR,
    WARM_STEPS,
    explained_without,
    hidden_marker_triangulated,
    one_left_out,
    reshared_warm_start,
    warm_start,
)

if TYPE_CHECKING:
    from core.anneal import SearchSpace
    from core.fit import FitParams

__all__ = ["TreeFlips", "attempt_kernel", "epipolar_start", "fit_tree", "refine_whole", "refine_without_lost",
           "refit_tree", "search_floor", "tree_flip_alternatives"]

CONFLICT_SWEEPS = 2
JOINT_STEPS = 10  # LM steps of the joint refinement: the parts arrive refined
WARM_JOINT_STEPS = 2  # joint refinement of parts that all came from warm starts
# A free root's triangulated start pairs blobs the detector may have merged within this
# share of the fusion distance more (``core.triangulate``): with two views, a random tree's
# root with two of its three markers on blobs merged with a limb's in one view had no
# candidate for the third, and SA, searching six DOFs on three markers, ended in another
# pose in ten images (docs/BENCH_SUBJECTS.md, stop 50). Not for the branches: every
# branch with two views tries its triangulated start, and the candidates that slack adds
# cost the 2-camera hexapod with glints a fifth of its rate.
TRUNK_MERGED_SHARE = 0.5


def attempt_kernel(dofs: np.ndarray, kin, points: np.ndarray, start: np.ndarray,
                   model: KinematicModel, rig: Rig, space: SearchSpace, params: FitParams,
                   eps: float, stream: np.ndarray, draw_start: bool, off: np.ndarray):
    """``_kernels.fit_attempt`` over the DOFs ``dofs`` (indices into ``model.dofs``) of the
    model posed by ``kin`` (the whole model, or one part) against detections ``points``
    (N, 3) grouped by view at ``start`` (V + 1,); returns (dofs (d,), error, objective,
    iterations, each SA run's final posture (r, d), the first's first)."""
    sa = kernel_params(params.anneal, space.sigma[dofs], space.table[dofs], eps=eps,
                       refine_result=params.refine, restarts=params.restarts,
                       search_edges=params.search_edges)
    image = kernel_image(points, start, params, off)
    runs = np.empty((params.restarts + 1, len(dofs)))
    q, error, objective, iterations, written = _kernels.fit_attempt(
        space.mean[dofs], bool(draw_start), _kernels.Bounds(model.lower[dofs], model.upper[dofs]), kin,
        rig.arrays, image, sa, stream, runs)
    return q, error, objective, iterations, runs[:written]


def _charged_objective(q: np.ndarray, kin, points: np.ndarray, start: np.ndarray, rig: Rig,
                       params: FitParams, off: np.ndarray) -> float:
    """The objective (pixels) of a posture ``q`` posed by ``kin`` (a part's or the whole
    model's) on detections ``points`` grouped at ``start`` as ``_kernels.fit_attempt``
    reports it and compares it with its stop: every marker projection charged (none left
    out as :func:`part_objective` leaves out the unseen ones), fusion below
    ``params.fusion_px``, and every view allowed to lose one marker at the empty-view
    penalty (the restarts' objective; the first run's, which loses none, is never lower)."""
    image = kernel_image(points, start, params, off)
    return float(_kernels.posture_error(q, kin, rig.arrays, image._replace(lost_px=image.penalty)))


def _search_stop(kept: np.ndarray, eps: float, kin, points: np.ndarray, start: np.ndarray, rig: Rig,
                 params: FitParams, off: np.ndarray) -> float:
    """SA's stop (pixels) for a part whose warm start did not stand in (in :func:`refit_tree`,
    its kept posture): that posture ``kept`` (d,), refined and posed by ``kin``, in the
    objective SA compares with its stop (:func:`_charged_objective`), or its ε ``eps`` where
    that is higher.

    A search that gets as low as the warm start has found its minimum or one as low, and
    running on to its patience and restarting rarely finds a lower one. Under sliding skin
    markers no part reaches its ε: with ε alone, every part whose warm start missed its
    ceiling ran SA to its patience and restarted, to end within a pixel of the warm start
    (the whole body's right leg, 37 of 60 images). In a first attempt this stop is used only
    where the warm start missed its ceiling as a slide does (:func:`missed_by_a_slide`)."""
    return max(eps, _charged_objective(kept, kin, points, start, rig, params, off))


def fit_tree(det: Detections, model: KinematicModel, rig: Rig, tree: Tree, space: SearchSpace,
             params: FitParams, stream: np.ndarray, draw_start: bool, off: np.ndarray,
             warm: np.ndarray | None = None,
             ceilings: Callable[[], Mapping[str, float]] | None = None
             ) -> tuple[np.ndarray, float, float, int, np.ndarray]:
    """One attempt on one image, part by part: (dofs (D,), plain Eq. 5 error, objective, SA
    iterations, searched (D,) bool), the first five of what :func:`core.fit.fit_image` returns. Each part
    first tries its posture in the warm starts ``warm`` (k, D) (:func:`warm_start`), and runs SA only
    where none reaches twice the part's ε or its ceiling in ``ceilings()`` (by part name,
    :func:`core.ceilings.warm_ceilings` of the previous image, asked for once, where a part first needs
    it), keeping the warm start where SA ends higher; where the best warm start missed its
    ceiling as sliding markers make it miss (:func:`missed_by_a_slide`), SA stops once as
    low as it (:func:`_search_stop`).
    A part that SA leaves above its ε, and above that stop, tries its triangulated start too
    (:func:`epipolar_start`), kept where it ends lower; with two views, every branch does
    (:func:`_two_view_starts`)."""
    q, error, objective, iterations, _, searched = _fit_tree(det, model, rig, tree, space, params, stream,
                                                             draw_start, off, warm, ceilings)
    return q, error, objective, iterations, searched


def refit_tree(det: Detections, model: KinematicModel, rig: Rig, tree: Tree, space: SearchSpace,
               params: FitParams, stream: np.ndarray, off: np.ndarray, keep: np.ndarray,
               typical: float = math.nan) -> tuple[np.ndarray, float, float, int, bool]:
    """A re-analysis attempt on a tree (``core.fit.reanalyse_image``), part by part given the
    kept posture ``keep`` (D,): (dofs (D,), plain Eq. 5 error, objective, SA iterations,
    settled), the first four as :func:`fit_tree` returns them.

    Each part, its base where the kept posture (or a part this attempt replaced before it)
    puts it, is searched by SA from a posture drawn from the histograms, and its kept
    posture, refined, is its warm start (:func:`warm_start`): the lower part objective
    (:func:`part_objective`) stays, then the whole posture is refined jointly. A whole
    attempt from a drawn start searches every part cold at once, and a part that lands in a
    worse minimum than the kept one throws the other parts' agreement away; here each part
    is the paper's re-analysis (§3.2: search again from a drawn start, keep the better) with
    the rest of the animal where the kept posture has it.

    A part's SA (its restarts too) stops below the kept part's level, the kept posture
    refined in the objective SA compares with its stop, or below its ε where that is higher
    (:func:`_search_stop`, as in :func:`fit_tree`): a drawn-start search that gets as low as the kept part has
    found its minimum or one as low, and running on to its patience and restarting rarely
    finds a lower one. Under sliding skin markers no part reaches its ε, so with ε alone
    every part's search would run to its patience and restart in every re-analysis. The
    triangulated start is tried only where SA ends at or above that stop: a search that got
    below the kept part's level has not failed (under sliding skin, where SA ends above ε in
    every re-analysis, the start was rarely kept and cost as much as the search).
    Whether the part gains and settled judge by its ε, as in :func:`fit_tree`.

    Why it cannot make a fit worse: a part is replaced only where its search ends lower on
    its own objective, the conflict sweeps and two-view starts judge as :func:`fit_tree`
    does, and ``core.fit.reanalyse_image`` keeps the attempt only where the whole objective
    is lower than the kept posture's.

    A part is settled unless its drawn-start search gains (:func:`_gains`: lower on its own
    objective by its ε or in another minimum, ``core.ambiguity.DISTINCT_DEG``, and lower on
    the whole objective with the rest of the posture as it is) and the attempt ends with
    the part in another minimum than the kept one. Searched again from an unrelated start
    it found its kept minimum or something higher, or blobs another part explains (lower on
    its own objective only, or taken back by the conflict sweeps): more attempts search the
    same way. A part whose kept posture reaches its ε skips SA (SA stops there) and is
    settled. So is a part whose kept posture, refined, is below its ceiling from the
    sequence's typical objective ``typical`` (pixels, NaN for none; :func:`typical_ceilings`):
    it is kept as a warm start under its ceiling is, without a search. Between ε and twice
    ε, where a first attempt's warm start stands in, a kept posture must be under that
    ceiling too: the image was re-analysed as an outlier, and a branch of two markers left
    in another minimum 2.1 px above the truth's (6 projections, ε 1.5 px) stood in in every
    attempt, 38° off, while the typical image fitted at 0.2 px (docs/BENCH_SUBJECTS.md,
    stop 56). ``settled`` is True
    when every part is (``core.fit.reanalyse_image`` settles an
    image whose attempt is not lower than the kept posture as well). A kept posture that
    reaches twice its ε only with a marker left out as hidden is searched where that marker's
    unexplained blobs meet in space (:func:`hidden_marker_triangulated`).
    """
    ceilings = (None if not math.isfinite(typical)
                else partial(typical_ceilings, keep, det, model, rig, params, off, typical))
    return _fit_tree(det, model, rig, tree, space, params, stream, True, off, keep[None], ceilings,
                     keep)[:5]


def _fit_tree(det: Detections, model: KinematicModel, rig: Rig, tree: Tree, space: SearchSpace,
              params: FitParams, stream: np.ndarray, draw_start: bool, off: np.ndarray,
              warm: np.ndarray | None, ceilings: Callable[[], Mapping[str, float]] | None,
              keep: np.ndarray | None = None
              ) -> tuple[np.ndarray, float, float, int, bool, np.ndarray]:
    """:func:`fit_tree`, or :func:`refit_tree` given the kept posture ``keep`` (D,) (then
    ``warm`` is ``keep[None]``): :func:`refit_tree`'s five values (settled False without
    ``keep``), then :func:`fit_tree`'s searched (:func:`_searched`)."""
    q = space.mean.copy() if keep is None else keep.copy()
    gained: list[Part] = []  # parts whose drawn-start search ended lower than ``keep``'s
    iterations = 0
    views_seen = det.views_seen
    shared = {} if warm is None else shared_projections(warm[0], model, rig, tree, params, off)
    candidates: list[Candidates] = []  # triangulated once, when a branch first needs them
    minima: dict[str, list[np.ndarray]] = {}  # per part, its SA runs' and warm start's postures
    asked: dict[str, float] = {}  # ``ceilings()``, once a part first needs it
    done = np.zeros(len(q), dtype=bool)  # the DOFs of the parts fitted so far in this attempt
    placed: dict[str, np.ndarray] = {}  # per part, a warm start that stood in under 2 ε (_searched)

    def levels(name: str) -> float:
        if not asked and ceilings is not None:
            asked.update(ceilings())
        return asked.get(name, math.nan)

    def fit_part(part: Part, points: np.ndarray, start: np.ndarray, warm: np.ndarray | None = None,
                 defer: bool = False) -> bool:
        """Fit ``part`` in ``q``, its base where the parts fitted before put it; with ``defer``,
        only where its warm start stands in for SA. Whether it is fitted."""
        nonlocal iterations
        rotation, origin = base_frame(q, model, part)
        kin = part.at(rotation, origin)
        eps = part_eps(part, params, views_seen)
        unseen = shared.get(part.name, _kernels.NO_UNSEEN)
        ceiling = None if ceilings is None else lambda: levels(part.name)
        done[part.dofs] = True
        # A re-analysis has every other part where the kept posture (or this attempt) has it.
        unexplained = None if keep is None else partial(hidden_marker_triangulated, q, part, points,
                                                         start, model, rig, params, off)
        tried = warm_start(part.dofs, kin, points, start, warm, model, rig, params, eps, off, unseen,
                           ceiling, unexplained)
        if tried is not None and not tried[2] and warm is not None:
            tried = reshared_warm_start(part, tried, np.where(done, q, warm[0]), kin, points, start, model,
                                        rig, tree, params, eps, off, unseen, ceiling, unexplained)
        if tried is not None and not tried[2] and warm is not None:
            tried = one_left_out(tried, part, kin, points, start, model, rig, params, eps, off, unseen)
        # A re-analysis keeps a part between ε and 2 ε without a search only under its ceiling.
        if (tried is not None and tried[2] and keep is not None and eps <= tried[1] < WARM_EPS_FACTOR * eps
                and ceiling is not None
                and not under_ceiling(tried[0], kin, rig, kernel_image(points, start, params, off, unseen),
                                      params, ceiling())):
            tried = (tried[0], tried[1], False)
        if tried is not None and tried[2]:
            q[part.dofs] = tried[0]
            if tried[1] < WARM_EPS_FACTOR * eps:
                placed[part.name] = tried[0]
            else:  # stood in above 2 ε: without its hidden projections, or under its ceiling
                placed.pop(part.name, None)
            return True
        if defer:
            done[part.dofs] = False
            return False
        placed.pop(part.name, None)
        at_level = tried is not None and (keep is not None or (
            ceiling is not None and missed_by_a_slide(tried[0], kin, points, start, unseen, rig, params, off,
                                                      ceiling())))
        stop = _search_stop(tried[0], eps, kin, points, start, rig, params, off) if at_level else eps
        q[part.dofs], _, _, its, runs = attempt_kernel(part.dofs, kin, points, start, model, rig, space,
                                                       params, stop, stream, draw_start, off)
        iterations += its
        minima.setdefault(part.name, []).extend([*runs, *([] if tried is None else [tried[0]])])
        value = part_objective(q[part.dofs], kin, points, start, unseen, rig, params, off)
        if keep is not None and tried is not None and _gains(q, part, value, tried, eps, det, model, rig,
                                                             params, off):
            gained.append(part)
        # Other minima replace SA's where lower in the objective SA compares its runs in, a
        # marker that looks hidden charged the empty-view penalty: charged its distance to some
        # other blob (part_objective), a leg whose claw is hidden scores above one in another
        # basin that puts the claw on another marker's blob.
        def lower(other: np.ndarray) -> bool:
            return (_charged_objective(other, kin, points, start, rig, params, off)
                    < _charged_objective(q[part.dofs], kin, points, start, rig, params, off))

        if tried is not None and lower(tried[0]):
            q[part.dofs], value = tried[0], tried[1]  # SA ended in a worse minimum than the warm start's
        if value >= stop:
            if part.base < 0:  # the root's trunk: its markers on blobs merged with a limb's pair too
                found = triangulate(det, rig=rig, offsets=off,
                                    merged_px=TRUNK_MERGED_SHARE * params.fusion_px)
            else:
                if not candidates:
                    candidates.append(triangulate(det, rig=rig, offsets=off))
                found = candidates[0]
            proposed = epipolar_start(part, rotation, origin, found, points, start, model,
                                      rig, space, params, eps, off, unseen)
            if proposed is not None and lower(proposed[0]):
                q[part.dofs] = proposed[0]
        return True

    branches = tree.branches  # parents first: a branch's base is fitted when it comes

    def fit_branches() -> np.ndarray:
        """Fit every branch in ``q`` given the trunk there: (B, N) the detections each reaches."""
        reach = np.zeros((len(branches), len(det.points)), dtype=bool)
        known = np.zeros(len(branches), dtype=bool)
        deferred: list[int] = []  # branches whose warm start did not stand in, on the last base

        def search_deferred() -> None:
            # Their warm starts tried again first: the branches on their base are in place
            # now, and where two legs touch, the fusion of their markers places each
            # (_fusions) only once both are where this image has them.
            for k in deferred:
                fit_part(branches[k], *subset(det, reach[k]), warm)
            deferred.clear()

        for b, part in enumerate(branches):
            if deferred and part.base != branches[deferred[0]].base:
                search_deferred()
            if not known[b]:  # every branch on this base at once: the base is fitted
                group = [k for k, p in enumerate(branches) if p.base == part.base]
                reach[group] = reaches(q, det, model, rig, [branches[k] for k in group], off)
                known[group] = True
            if not fit_part(part, *subset(det, reach[b]), warm, defer=warm is not None):
                deferred.append(b)
        search_deferred()
        return reach

    if tree.trunk is not None:
        fit_part(tree.trunk, det.kernel_points, det.start, warm)
    reach = fit_branches()
    if tree.trunk is not None and _trunk_unexplained(q, det, model, rig, tree, params, off):
        # Its own markers leave the trunk unexplained (hidden, or on a branch's blobs): the
        # trunk judged by the whole model, then the branches refitted given it, kept where
        # the whole objective is lower.
        before, reach_before = q.copy(), reach
        _trunk_by_whole(q, det, model, rig, tree, params, off, warm)
        if distinct(q[tree.trunk.dofs], before[tree.trunk.dofs], model.rotational[tree.trunk.dofs]):
            reach = fit_branches()
            if _whole_objective(q, det, model, rig, params, off) >= _whole_objective(
                    before, det, model, rig, params, off):
                q[:], reach = before, reach_before
        else:
            q[:] = before
    in_reach = reach.any(axis=0)
    score = np.inf  # the two-sided error, computed once there is a conflict to judge
    previous: list[int] = []
    for _ in range(CONFLICT_SWEEPS):
        contested = contested_projections(q, det, model, rig, tree, off)
        conflicted = [b for b, part in enumerate(branches) if contested[:, part.markers].any()]
        if not conflicted or conflicted == previous:
            break
        previous = conflicted
        if score == np.inf:
            score = two_sided_error(q, det, model, rig, off, in_reach, params.empty_view_penalty_px)
        for b in conflicted:
            part, saved = branches[b], q.copy()
            free = reaches(q, det, model, rig, [part], off)[0] & ~claimed(q, det, model, rig, tree, off,
                                                                          exclude=b)
            points, start = subset(det, free)
            if explained_without(part, q, contested[:, part.markers], det, points, start, model, rig,
                                 params, off, views_seen, shared.get(part.name, _kernels.NO_UNSEEN)):
                continue
            fit_part(part, points, start)
            new = two_sided_error(q, det, model, rig, off, in_reach, params.empty_view_penalty_px)
            if new < score:
                score = new
            else:
                q[:] = saved
    if views_seen == 2:  # two views: a wrong leg can explain every blob it projects onto
        if not candidates:
            candidates.append(triangulate(det, rig=rig, offsets=off))
        _two_view_starts(q, det, model, rig, tree, space, params, off, reach, candidates[0], shared, minima)
    # Parts that all came from warm starts arrive at ε on their own projections, refined:
    # the joint steps (each costing D evaluations) only read the blobs parts share as fused.
    steps = JOINT_STEPS if iterations else WARM_JOINT_STEPS
    q, error, objective = refine_whole(q, det, model, rig, params, off, steps)
    rot = model.rotational
    settled = keep is not None and not any(distinct(q[p.dofs], keep[p.dofs], rot[p.dofs]) for p in gained)
    return q, error, objective, iterations, settled, _searched(q, tree, placed, rot)


def _searched(q: np.ndarray, tree: Tree, placed: Mapping[str, np.ndarray], rot: np.ndarray) -> np.ndarray:
    """(D,) bool: False for the DOFs of each part a warm start placed and True elsewhere.

    Placed (``placed``, by part name): the warm start stood in for SA with its part
    objective under :data:`WARM_EPS_FACTOR` times the part's ε, and the part is still
    within :data:`~core.ambiguity.DISTINCT_DEG` of it in ``q`` (the conflict sweeps, the
    trunk judged by the whole model, the two-view starts or the joint refinement did not
    move it away). A warm start that stood in above that objective, once its hidden
    projections were left out or under its ceiling, leaves the part searched: the image
    judged it less closely, and the previous posture refined may land in another minimum
    that the choice by continuity needs (``core.fit._warm_alternatives``)."""
    searched = np.ones(len(q), dtype=bool)
    for part in tree.parts:
        if part.name in placed and not distinct(q[part.dofs], placed[part.name], rot[part.dofs]):
            searched[part.dofs] = False
    return searched


def _trunk_unexplained(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, tree: Tree,
                       params: FitParams, off: np.ndarray) -> bool:
    """Whether, at posture ``q`` (D,), some projection of the root trunk's markers (in a view
    with detections) is not explained by a blob of its own: farther than the empty-view
    penalty from every blob (hidden), or nearest a blob that a branch's marker claims too
    (within :data:`CLAIM_PX` of both: a hidden trunk marker on a limb's blob)."""
    trunk = tree.trunk
    assert trunk is not None
    proj = rig.project(model.marker_positions(q)) + off[:, None, :]
    branch = np.setdiff1d(np.arange(len(model.markers)), trunk.markers)
    for v in range(det.n_views):
        pts = det.view(v)
        if len(pts) == 0:
            continue
        d = np.linalg.norm(proj[v][trunk.markers][:, None, :] - pts[None], axis=2)  # (m, n)
        nearest = d.min(axis=1)
        if (nearest > params.empty_view_penalty_px).any():
            return True
        near = d.argmin(axis=1)[nearest <= CLAIM_PX]
        if len(near) and len(branch):
            to_branch = np.linalg.norm(proj[v][branch][:, None, :] - pts[near][None], axis=2).min(axis=0)
            if (to_branch <= CLAIM_PX).any():
                return True
    return False


def _trunk_by_whole(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, tree: Tree,
                    params: FitParams, off: np.ndarray, warm: np.ndarray | None) -> None:
    """The root trunk's DOFs of ``q`` (D,) (changed in place) refined by LM on every marker
    of the model, every other DOF held (:func:`_rigid_trunk`), from ``q`` and from each warm
    start ``warm`` (k, D) (its branches held as it has them); the lowest whole objective
    (:func:`_charged_objective`) stays. Held, the branches ride rigidly on the trunk joints
    they hang from, so their markers place the trunk as its own do.

    Why: a trunk whose own markers are hidden, in a view or two, is charged their distance
    to the nearest blob, some limb's; its own objective is then lower at a wrong posture
    that puts them on limb blobs than at the right one, which leaves them unexplained. The
    limbs' proximal markers (a trochanter, a shoulder) lie a few millimetres from the trunk
    whatever the limb's posture, and charge the wrong trunk. The previous image's whole
    posture (a warm start) moved little as a whole since. LM only: SA over the trunk on
    every marker, tried in re-analysis as well, fixed nothing more on the benchmarks and
    halved the occluded biped's and rat's rates (docs/BENCH_SUBJECTS.md)."""
    trunk = tree.trunk
    assert trunk is not None
    dofs = trunk.dofs
    image = whole_image(det, params, off)
    bounds = _kernels.Bounds(model.lower[dofs], model.upper[dofs])
    rows = [q] if warm is None else [q, *warm]  # read only: the trunk is written last
    best, best_value = q[dofs].copy(), np.inf
    for row in rows:
        kin = _rigid_trunk(row, model, trunk)
        t = np.ascontiguousarray(row[dofs])
        if params.refine:
            t = _kernels.refine(t, bounds, kin, rig.arrays, image, float(params.anneal.huber_px), WARM_STEPS,
                                _kernels.NO_TARGETS)
        value = _charged_objective(t, kin, det.kernel_points, det.start, rig, params, off)
        if value < best_value:
            best, best_value = t, value
    q[dofs] = best


def _rigid_trunk(q: np.ndarray, model: KinematicModel, trunk: Part):
    """The root trunk's arrays (``trunk.kin``) carrying every other marker of the model too,
    each fixed in the frame of the deepest trunk joint above it where ``q`` (D,) puts it: the
    whole model with every DOF outside the trunk held."""
    others = np.setdiff1d(np.arange(len(model.markers)), trunk.markers)
    below = _subtrees(model.arrays.parent)
    on = np.array([int(trunk.joints[below[trunk.joints, j]].max())
                   for j in model.arrays.marker_joint[others]], dtype=np.int64)
    rot, pos = world_frames(q, model)
    world = model.marker_positions(q)[others]
    local = np.einsum("kji,kj->ki", rot[on], world - pos[on])  # R^T (x - p)
    row = {int(j): i for i, j in enumerate(trunk.joints)}
    kin = trunk.kin
    return kin._replace(
        marker_joint=np.concatenate([kin.marker_joint, [row[int(j)] for j in on]]).astype(np.int64),
        marker_pos=np.ascontiguousarray(np.vstack([kin.marker_pos, local])))


def search_floor(model: KinematicModel, params: FitParams, views_seen: int) -> float:
    """The objective (pixels) below which every part of ``model`` is within the ε its search
    stops at, in an image with detections in ``views_seen`` views: ε (``AnnealParams.eps``)
    for a model fitted whole (``model.tree`` None), the smallest of its parts' ε
    (:func:`part_eps`) for a tree.

    An image scoring under it ends where another attempt's search would stop as well, so
    it is no outlier to re-analyse, however far above the sequence's typical objective
    (``core.fit.needs_reanalysis``): a hexapod's thorax (3 markers) seen in 3 views stops at
    2.25 px. Not the sum of the parts' ε (40.5 px in 6 views): one leg 39° off in another
    basin, 31 px above the rest, hid under it (docs/BENCH_SUBJECTS.md, the fly at 50 Hz).

    >>> from core.fit import FitParams
    >>> from core.examples import LOCUST
    >>> search_floor(KinematicModel.from_xml(LOCUST / "model.xml"), FitParams(), 2)
    1.0
    """
    if model.tree is None:
        return params.anneal.eps
    return float(min(part_eps(part, params, views_seen) for part in model.tree.parts))


def _two_view_starts(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, tree: Tree,
                     space: SearchSpace, params: FitParams, off: np.ndarray, reach: np.ndarray,
                     candidates: Candidates, shared: dict[str, np.ndarray],
                     minima: Mapping[str, list[np.ndarray]]) -> None:
    """Each branch's triangulated start (:func:`epipolar_start`), and each posture of it in
    ``minima`` (by part name: the minima of its SA runs and its warm start, (d,) each),
    replaces its posture in ``q`` (D,) (changed in place) where that lowers the two-sided
    error over the blobs in reach (``reach`` (B, N), per branch), a minimum by more than the
    cap (the empty-view penalty: one blob explained more); a branch's base is where ``q``
    puts it when it comes.

    With two views every pair of blobs on corresponding epipolar lines is a 3D point, so a
    leg posed on another leg's blobs or on ghosts can explain all it projects onto, below
    ε, and only the blobs it leaves unexplained (the two-sided error) tell it from the
    right one. Its SA keeps the run of lowest objective, which charges the hidden markers
    of the right posture their distance to some other blob beyond one a view: with a
    marker hidden from each camera, or two from one, a leg on other blobs scores lower,
    and another of its runs often ended at the right one. The margin: SA ranked its minima
    in its own objective, and under sliding skin markers their two-sided errors differ by
    a few pixels whichever is right.

    A branch is posed onto the candidates only where one of them may move it
    (:func:`_concerned_branches`): a leg on wrong blobs leaves its right ones unexplained,
    while a leg that explains its blobs would be posed back where it is, at 2-3 ms a
    branch."""
    in_reach = reach.any(axis=0)
    cap = params.empty_view_penalty_px
    score = two_sided_error(q, det, model, rig, off, in_reach, cap)
    concerned = _concerned_branches(q, det, model, rig, tree, off, candidates, reach)
    for part, keep, offered in zip(tree.branches, reach, concerned, strict=True):
        starts = [(p, cap) for p in minima.get(part.name, ())]  # (posture, margin)
        if offered:
            points, start = subset(det, keep)
            rotation, origin = base_frame(q, model, part)
            proposed = epipolar_start(part, rotation, origin, candidates, points, start,
                                      model, rig, space, params, part_eps(part, params, 2), off,
                                      shared.get(part.name, _kernels.NO_UNSEEN))
            if proposed is not None:
                starts.append((proposed[0], 0.0))
        for posture, margin in starts:
            trial = q.copy()
            trial[part.dofs] = posture
            if (new := two_sided_error(trial, det, model, rig, off, in_reach, cap)) < score - margin:
                q[:], score = trial, new


def _concerned_branches(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, tree: Tree,
                        off: np.ndarray, candidates: Candidates, reach: np.ndarray) -> np.ndarray:
    """(B,) bool: the branches that triangulated ``candidates`` may move, ``q`` (D,) as it
    is: those with a marker projection that no blob of its view explains (none within
    :data:`CLAIM_PX`: hidden, or the branch off its blobs), and those a candidate concerns.
    A candidate concerns a branch where it has a blob that no marker projection explains,
    every blob in the branch's reach (``reach`` (B, N)), and its other blobs unexplained too
    or explained by the branch's own markers."""
    proj = rig.project(model.marker_positions(q)) + off[:, None, :]  # (V, M, 2)
    claiming, owner = claiming_at(proj, det, tree)
    by_branch = claims_of(claiming, owner, len(tree.branches), len(det.points))  # (B, N)
    explained = explained_blobs(proj, det.points, det.start, CLAIM_PX)
    support = candidates.support
    blob, real = np.maximum(support, 0), support >= 0  # (K, V)
    open_ = (~explained[blob] & real).any(axis=1)  # (K,)
    inside = (reach[:, blob] | ~real).all(axis=2)  # (B, K)
    mine = (by_branch[:, blob] | ~explained[blob] | ~real).all(axis=2)  # (B, K)
    unclaimed = (claiming < 0)[seen_views(det.start)]  # (seen V, M)
    off_blobs = np.array([unclaimed[:, part.markers].any() for part in tree.branches], dtype=bool)
    return off_blobs | (open_ & inside & mine).any(axis=1)


def epipolar_start(part: Part, rotation: np.ndarray, origin: np.ndarray, candidates: Candidates,
                   points: np.ndarray, start: np.ndarray, model: KinematicModel, rig: Rig,
                   space: SearchSpace, params: FitParams, eps: float, off: np.ndarray,
                   unseen: np.ndarray) -> tuple[np.ndarray, float, bool] | None:
    """A part posed onto the image's triangulated ``candidates`` from the histogram mean (a
    branch by ``core.epipolar_start.branch_start``, its base at ``rotation`` (3, 3) and
    ``origin`` (3,); the root's trunk by ``core.epipolar_start.trunk_start``), then refined
    like a warm start (:func:`warm_start`) on the detections ``points`` grouped at ``start``:
    (posture (d,), objective, reaches 2 ε), or None when too few candidates fit the part."""
    common = dict(part=part, q0=space.mean[part.dofs], model=model, rig=rig, points=points, start=start,
                  offsets=off, empty_view_penalty_px=float(params.empty_view_penalty_px))
    proposed = (trunk_start(candidates, **common) if part.base < 0
                else branch_start(candidates, rotation=rotation, origin=origin, **common))
    if proposed is None:
        return None
    row = space.mean.copy()
    row[part.dofs] = proposed.dofs
    return warm_start(part.dofs, part.at(rotation, origin), points, start, row[None], model, rig,
                      params, eps, off, unseen)


def _gains(q: np.ndarray, part: Part, value: float, kept: tuple[np.ndarray, float, bool], eps: float,
           det: Detections, model: KinematicModel, rig: Rig, params: FitParams, off: np.ndarray) -> bool:
    """Whether ``part``'s drawn-start search in :func:`refit_tree`, its posture in ``q`` (D,)
    of part objective ``value``, ended lower than its kept posture ``kept`` (posture, part
    objective, _ from :func:`warm_start`): on the part's own objective, by its ε or in
    another minimum (``core.ambiguity.DISTINCT_DEG``), and on the whole objective with the
    rest of ``q`` as it is. A part lower on its own detections only has taken blobs another
    part explains (its objective never charges a blob it leaves unexplained)."""
    if not value < kept[1] or (value > kept[1] - eps and not distinct(
            q[part.dofs], kept[0], model.rotational[part.dofs])):
        return False
    other = q.copy()
    other[part.dofs] = kept[0]
    return _whole_objective(q, det, model, rig, params, off) < _whole_objective(
        other, det, model, rig, params, off)


def _whole_objective(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                     params: FitParams, off: np.ndarray) -> float:
    """:func:`_charged_objective` of a whole posture ``q`` (D,) on ``det``: what
    :func:`refine_whole` minimises before its refit without the markers that look lost
    (``_kernels._refit_unseen``, which charges each of those the penalty instead)."""
    return _charged_objective(q, model.arrays, det.kernel_points, det.start, rig, params, off)


def refine_whole(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                 params: FitParams, off: np.ndarray,
                 steps: int = JOINT_STEPS) -> tuple[np.ndarray, float, float]:
    """Joint refinement of a whole posture ``q`` (changed in place) by ``steps`` LM steps:
    (posture, plain Eq. 5 error, objective), the objective as ``_kernels.fit_attempt``
    reports it (fusion, a lost marker per view)."""
    a, kin, views = params.anneal, model.arrays, rig.arrays
    bounds = _kernels.Bounds(model.lower, model.upper)
    image = whole_image(det, params, off)

    def objective(p: np.ndarray) -> float:
        return _whole_objective(p, det, model, rig, params, off)

    value = objective(q)
    if params.refine and steps > 0:
        polished = _kernels.refine(q, bounds, kin, views, image, float(a.huber_px), steps,
                                   _kernels.NO_TARGETS)
        if (e := objective(polished)) <= value:
            q, value = polished, e
    if params.refine:
        value = _kernels._refit_unseen(q, value, bounds, kin, views, image, float(a.huber_px))
    error = _kernels.plain_error(q, kin, views, image)
    return q, float(error), float(value)


def refine_without_lost(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                        params: FitParams, off: np.ndarray
                        ) -> tuple[np.ndarray, float, float, np.ndarray] | None:
    """A whole posture ``q`` (D,) refined by :data:`JOINT_STEPS` LM steps on ``det`` without
    the projections that look hidden at ``q`` itself: (posture, plain Eq. 5 error, objective
    as :func:`refine_whole` reports it, those projections (V, M) bool); None
    where none look hidden, more than :data:`core.ceilings.MAX_LOST_SHARE` of the compared projections do,
    or those left do not lie in two views (:func:`core.ceilings.judged_in_two_views`).

    Hidden as :func:`left_out_with_lost` reads them, as :func:`core.warm_start._without_lost` does for a
    part's warm start, but before any refinement: refined with them, the posture slides
    until each lands on some other blob, a ghost or a neighbour's marker, and the reading is
    lost with it.
    """
    image = whole_image(det, params, off)
    if (lost := left_out_with_lost(q, model.arrays, rig, image)) is None:
        return None
    refined = _kernels.refine(np.ascontiguousarray(q), _kernels.Bounds(model.lower, model.upper),
                              model.arrays, rig.arrays, image._replace(unseen=lost),
                              float(params.anneal.huber_px), JOINT_STEPS, _kernels.NO_TARGETS)
    error = _kernels.plain_error(refined, model.arrays, rig.arrays, image)
    return refined, float(error), _whole_objective(refined, det, model, rig, params, off), lost


@dataclass(frozen=True)
class TreeFlips:
    """What :func:`tree_flip_alternatives` needs of a tree model and a rig, built once per
    chunk: the whole model's depth-flip geometry (``FlipGeometry.of``) kept to the flips that
    move no branch alone (searched on the whole model: the trunk's, and those of a branch's
    own trunk, which carry other branches along), and each branch's own geometry over its
    joints ``Part.flips`` (None for a branch without any), in ``tree.branches`` order."""

    trunk: FlipGeometry
    branches: tuple[FlipGeometry | None, ...]

    @classmethod
    def of(cls, geometry: FlipGeometry, model: KinematicModel) -> TreeFlips:
        """The tree flips of ``model`` (with a tree) from its whole ``geometry``."""
        tree = model.tree
        assert tree is not None
        trunk = geometry._replace(masks=geometry.masks[_trunk_masks(geometry, model, tree)])
        return cls(trunk, tuple(_branch_geometry(part, geometry) if len(part.flips) else None
                                for part in tree.branches))


def tree_flip_alternatives(fit: Candidate, detections: Detections, *, model: KinematicModel,
                           rig: Rig, geometry: TreeFlips, tolerance_px: float, fusion_px: float,
                           empty_view_penalty_px: float, huber_px: float,
                           offsets: np.ndarray | None = None) -> list[Candidate]:
    """``core.ambiguity.flip_alternatives`` for a tree, branch by branch: the same depth flips,
    each branch's (``Part.flips``) scored on that branch's markers alone, then the fit with
    the flipped branch scored whole and kept within ``tolerance_px`` of it; the trunk's flips
    and those of a branch's own trunk (which carry other branches along) on the whole model.
    Up to ``MAX_ALTERNATIVES``, best first.

    A flip below a branch joint moves that branch's markers only, so scoring it on the
    whole model (27 markers in 6 views for the hexapod, 180 flips an image) repeats the
    other branches' unchanged cost every time.
    """
    tree, off = model.tree, view_offsets(offsets, rig)
    assert tree is not None
    views = rig.arrays
    image = _kernels.Image.of(detections.kernel_points, detections.start, off, penalty=empty_view_penalty_px,
                              fuse_px=fusion_px)
    found = flip_alternatives(fit, detections, model=model, rig=rig, geometry=geometry.trunk,
                              tolerance_px=tolerance_px, fusion_px=fusion_px,
                              empty_view_penalty_px=empty_view_penalty_px, huber_px=huber_px,
                              offsets=offsets)
    rot, pos = world_frames(fit.dofs, model)
    for part, geo in zip(tree.branches, geometry.branches, strict=True):
        if geo is None:  # a branch's own trunk: flipped with the whole model
            continue
        kin, q = part.at(rot[part.base], pos[part.base]), np.ascontiguousarray(fit.dofs[part.dofs])
        out_q, out_objective = np.empty((MAX_ALTERNATIVES, len(q))), np.empty(MAX_ALTERNATIVES)
        own = _kernels.posture_error(q, kin, views, image)
        n = _kernels.flip_alternatives(
            q, own, float(tolerance_px), _kernels.Bounds(model.lower[part.dofs], model.upper[part.dofs]),
            kin, views, image, float(huber_px), geo, MAX_FLIP_REFINES, out_q, out_objective)
        for k in range(n):
            whole = fit.dofs.copy()
            whole[part.dofs] = out_q[k]
            objective = float(_kernels.posture_error(whole, model.arrays, views,
                                                     image._replace(lost_px=image.penalty)))
            if objective <= fit.objective + tolerance_px:
                error = _kernels.plain_error(whole, model.arrays, views, image)
                found.append(Candidate(whole, float(error), objective))
    return sorted(found, key=lambda c: c.objective)[:MAX_ALTERNATIVES]


def _trunk_masks(geometry: FlipGeometry, model: KinematicModel, tree: Tree) -> np.ndarray:
    """(K,) bool: the masks of ``geometry`` (the whole model's) that flip no branch joint, a
    joint whose subtree holds markers of one branch only (``Part.flips``) or none."""
    in_branch = np.zeros(len(geometry.flip_joints), dtype=bool)
    for part in tree.branches:
        in_branch |= ~geometry.subtree_markers[:, outside(part, len(model.markers))].any(axis=1)
    bits = int(np.sum(np.left_shift(1, np.flatnonzero(in_branch).astype(np.int64))))
    return (geometry.masks & bits) == 0


def _branch_geometry(part: Part, geometry: FlipGeometry) -> FlipGeometry:
    """The depth-flip geometry of one branch alone (its arrays, base first) over its joints
    ``part.flips``, the views' depth directions from the whole model's ``geometry``."""
    kin = part.kin
    below = _subtrees(kin.parent)[part.flips]
    return geometry._replace(flip_joints=part.flips, subtree_joints=below,
                             subtree_markers=np.ascontiguousarray(below[:, kin.marker_joint]),
                             masks=flip_masks(len(part.flips)))
