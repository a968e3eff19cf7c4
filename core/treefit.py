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

Within a chunk, each part first tries the previous image's posture (:func:`warm_start`):
refined on the part's detections, it replaces the part's SA where it reaches twice the
part's ε or, under sliding skin markers, the part's level in the previous image plus what
its residual cannot tell apart (:func:`core.ceilings.warm_ceilings`), or on its other projections with
those of markers that look hidden left out (:func:`_without_lost`). One that misses is
tried again after the other branches on its base are fitted, without the projections this
image's postures put on another part's marker or a merged blob
(:func:`_reshared_warm_start`); when every part came
from a warm start the joint refinement takes
:data:`WARM_JOINT_STEPS` steps: at 50-200 Hz most parts of most images skip SA (figures in
docs/BENCH_SUBJECTS.md). Depth flips are searched branch by branch
(:func:`tree_flip_alternatives`). A part that SA leaves above its ε (with two or more
views) tries one more start, triangulated from the blobs (:func:`epipolar_start`,
``core.triangulate``), refined like a warm start and kept where it ends lower: a branch
posed onto the candidates within its reach, the root's trunk onto three candidates that
lie as its markers do (a free trunk searched from the middle of its translation ranges
can end on the wrong blobs, and every branch then hangs from the wrong place). With two
views every branch tries it, and every SA run's minimum of it and its warm start, kept where
it lowers the two-sided error (:func:`_two_view_starts`): there a leg on the wrong blobs can
explain all it projects onto, and the run SA ranks lowest can be one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from itertools import pairwise
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
    MAX_LOST_SHARE,
    compared_count,
    judged_in_two_views,
    left_out_with_lost,
    missed_by_a_slide,
    typical_ceilings,
    under_ceiling,
)
from core.claims import (
    CLAIM_PX,
    FUSED_PX,
    claimed,
    claiming_at,
    claims_of,
    contested_projections,
    explained_blobs,
    on_merged_blobs,
    reaches,
    shared_projections,
    subset,
    two_sided_error,
)
from core.epipolar_start import branch_start, trunk_start
from core.error import Detections, nearest_detection, view_offsets
from core.identifiability import marker_jacobian
from core.model import KinematicModel
from core.part_objective import (
    base_frame,
    in_seen_views,
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

if TYPE_CHECKING:
    from core.anneal import SearchSpace
    from core.fit import FitParams

__all__ = ["TreeFlips", "attempt_kernel", "epipolar_start", "fit_tree", "refine_whole", "refine_without_lost",
           "refit_tree", "search_floor", "tree_flip_alternatives", "warm_start"]

CONFLICT_SWEEPS = 2
JOINT_STEPS = 10  # LM steps of the joint refinement: the parts arrive refined
WARM_STEPS = 10  # LM steps refining the previous image's posture of a part (a warm start)
WARM_JOINT_STEPS = 2  # joint refinement of parts that all came from warm starts
WARM_EPS_FACTOR = 2.0  # a warm start stands in for SA within this many times the part's ε
HIDDEN_SEEN_VIEWS = 3  # unexplained blobs of this many views meeting in space: a marker not hidden


def attempt_kernel(dofs: np.ndarray, kin, points: np.ndarray, start: np.ndarray,
                   model: KinematicModel, rig: Rig, space: SearchSpace, params: FitParams,
                   eps: float, stream: np.ndarray, draw_start: bool, off: np.ndarray):
    """``_kernels.fit_attempt`` over the DOFs ``dofs`` (indices into ``model.dofs``) of the
    model posed by ``kin`` (the whole model, or one part) against detections ``points``
    (N, 3) grouped by view at ``start`` (V + 1,); returns (dofs (d,), error, objective,
    iterations, each SA run's final posture (r, d), the first's first)."""
    sa = kernel_params(params.anneal, space.sigma[dofs], space.table[dofs], eps=eps,
                       refine_result=params.refine, restarts=params.restarts)
    image = kernel_image(points, start, params, off)
    runs = np.empty((params.restarts + 1, len(dofs)))
    q, error, objective, iterations, written = _kernels.fit_attempt(
        space.mean[dofs], bool(draw_start), _kernels.Bounds(model.lower[dofs], model.upper[dofs]), kin,
        rig.arrays, image, sa, stream, runs)
    return q, error, objective, iterations, runs[:written]


def warm_start(dofs: np.ndarray, kin, points: np.ndarray, start: np.ndarray, warm: np.ndarray | None,
               model: KinematicModel, rig: Rig, params: FitParams, eps: float, off: np.ndarray,
               unseen: np.ndarray = _kernels.NO_UNSEEN,
               ceiling: Callable[[], float] | None = None,
               unexplained: Callable[[np.ndarray, np.ndarray], bool] | None = None,
               ) -> tuple[np.ndarray, float, bool] | None:
    """The warm starts ``warm`` (k, D), each one's posture of the DOFs ``dofs`` (a part posed
    by ``kin``) refined on detections ``points`` (N, 3) grouped at ``start`` (V + 1,) by
    :data:`WARM_STEPS` LM steps: (posture (d,), objective in pixels, whether it stands in
    for SA) of the first that reaches :data:`WARM_EPS_FACTOR` times ``eps`` (SA's stop), or
    does on its other projections once those that look hidden are left out
    (:func:`_without_lost`), else of the lowest objective, which stands in for SA where it
    is below ``ceiling()`` (pixels per compared projection, :func:`core.ceilings.warm_ceilings`:
    the part's level in the previous image plus what a residual at that level cannot tell
    apart; asked for only there); None without ``warm``.

    Why more than ε: where a warm start misses ε by a little, the part's minimum itself is
    above it (a ghost blob merged with a marker in one view, say), and SA only runs to its
    patience to end in the same minimum; a warm start in another minimum costs far more
    (a wrong leg is pixels off in several views), and a depth flip that costs as little is
    offered as an alternative either way (``core.ambiguity``).

    Why the ceiling: with sliding skin markers no posture of a part reaches 2 ε, and the
    minimum's own level is the markers' slide, which varies slowly from image to image. SA
    can change the answer only by finding a posture lower than the warm start's by more
    than the part's residual can tell apart (``core.undetermined.residual_tolerance``); a
    warm start within that of the previous image's level leaves it none to find unless the
    slide dropped by more than that in one image. Why it is safe: a warm start in another
    basin costs the level plus a leg pixels off in several views, above the ceiling, and
    runs SA (kept only where SA ends higher); one within the ceiling is one this image's
    residual does not tell from the part's minimum. The level is the part's lowest over the
    previous fit and its alternatives (``core.sequence.fit_chunk``), so a part that the
    whole objective put in another minimum than its own best is searched again. Both the
    level and the warm start charge a projection that looks hidden the empty-view penalty
    (:func:`core.ceilings._ceiling_level`): at its distance to some other blob, one hidden marker raised
    the next image's ceiling by tens of pixels, and a leg in another basin stood in for SA
    (2-camera hexapod, 10 % of projections hidden: 97 of 116 such warm starts). A branch
    most of whose projections looked hidden has no ceiling (:func:`core.ceilings.warm_ceilings`). The image's
    depth flips and undetermined DOFs are still searched (``core.fit``), and a chunk's first
    image runs SA on every part. A re-analysis judges its kept posture by ceilings from the
    sequence's typical objective instead (:func:`typical_ceilings`).

    ``unexplained(q, hidden)``, where given (a re-analysis), says whether a marker the part
    at posture ``q`` (d,) leaves out as hidden (``hidden`` (V, m)) has unexplained blobs in
    those views that meet in space (:func:`_hidden_marker_triangulated`); such a warm start
    does not stand in (:func:`_without_lost`).

    ``unseen`` (V, m) bool marks projections next to another part's marker
    (:func:`shared_projections`): they are left out of the refinement and of the objective
    (:func:`part_objective`), and ``eps`` (per projection) shrinks in proportion. Such a
    blob is two markers fused, off each by pixels, which no posture of this part alone
    explains: left in, it keeps a leg that fits everywhere else above ε (the joint
    refinement reads it as fused). They are read at the posture the warm start came from,
    so a warm start judged without them must leave every DOF placed in two views (one with
    two cameras, :func:`_left_in_too_few_views`): at 50 Hz the free fly's hind claw, next
    to another leg's marker in the previous image, was left out in enough views to free
    the tarsus, and the warm start stood in 25° off. Nor may leaving them out free a
    direction that no single DOF shows, two DOFs turning against each other
    (:func:`_freed_by_leaving_out`).

    A warm start stands in only where the projections it is judged on lie in two views,
    wherever the part has detections in two or more (:func:`judged_in_two_views`): the claim
    that another basin costs far more rests on its being pixels off in several views. In one
    view a limb's depth flips cost nothing, and the refinement can turn it into a posture
    that explains that view alone (a forelimb whose side-view markers all lie next to the
    other forelimb's, its wrist hidden from below, ended 62° off).

    At 50-200 Hz a part has moved a few degrees since the previous image, inside the
    basin LM descends; where it moved farther, or the previous posture lies in a minimum
    this image no longer supports, the refined posture stays above ``eps``.
    """
    if warm is None:
        return None
    unseen = in_seen_views(unseen, start)
    if unseen.size:
        eps *= 1.0 - np.count_nonzero(unseen) / max(unseen.shape[1] * np.count_nonzero(seen_views(start)), 1)
    best: tuple[np.ndarray, float, bool] | None = None
    image = kernel_image(points, start, params, off, unseen)
    bounds = _kernels.Bounds(model.lower[dofs], model.upper[dofs])
    views = judged_in_two_views(unseen, start)
    rot = model.rotational[dofs]
    for row in warm:
        q = np.ascontiguousarray(row[dofs])
        if params.refine:
            q = _kernels.refine(q, bounds, kin, rig.arrays, image, float(params.anneal.huber_px), WARM_STEPS,
                                _kernels.NO_TARGETS)
        value = part_objective(q, kin, points, start, unseen, rig, params, off)
        if value < WARM_EPS_FACTOR * eps and views and not (
                unseen.any() and (_left_in_too_few_views(unseen, q, kin, image)
                                  or _freed_by_leaving_out(q, rot, kin, rig, image,
                                                           params.alternative_tolerance_px))):
            return q, value, True
        if params.refine and views and (seen := _without_lost(q, row[dofs], kin, image, bounds, rig,
                                                              params, eps, unexplained)) is not None:
            return seen, part_objective(seen, kin, points, start, unseen, rig, params, off), True
        if best is None or value < best[1]:
            best = (q, value, False)
    if best is not None and ceiling is not None and views:
        best = (best[0], best[1], under_ceiling(best[0], kin, rig, image, params, ceiling()))
    return best


def _freed_by_leaving_out(q: np.ndarray, rot: np.ndarray, kin, rig: Rig, image: _kernels.Image,
                          floor_px: float) -> bool:
    """Whether leaving out the projections ``image.unseen`` marks frees a direction of the
    rotational DOFs ``rot`` (d,) bool of a part at posture ``q`` (d,) (posed by ``kin``)
    where some marker is left out of every view with detections: a
    ``core.undetermined.UNDETERMINED_DEG`` step along it moves the projections left by less
    than ``floor_px`` (norm, pixels), while it moves all of them by more. Where every
    marker is compared in some view, False without reading the Jacobian: a warm start with
    a shared projection is tried in most images.

    Why: each DOF may still move some projection left (:func:`_left_in_too_few_views`)
    while two DOFs together move none of them. With its femur-tibia marker left out of
    both of two views, a fly's middle leg turns its coxa roll against its femur roll and
    keeps its distal markers where they were (0.03 px per degree along that direction
    against 0.26 with the marker): its warm start stood in 16° off, ``ok``, 16 px above
    the truth in the whole objective (docs/BENCH_SUBJECTS.md, glints)."""
    from core.undetermined import UNDETERMINED_DEG  # it imports this module

    seen = seen_views(image.start)[:, None]
    columns = np.flatnonzero(rot)
    if (seen & ~image.unseen).any(axis=0).all() or not columns.size:
        return False
    steps = np.repeat(q[None], len(columns) + 1, axis=0)
    steps[np.arange(1, len(columns) + 1), columns] += 1.0  # one degree each
    proj = rig.project(_kernels.marker_positions_many(steps, kin))  # (k + 1, V, m, 2)
    moved = proj[1:] - proj[:1]  # (k, V, m, 2): pixels per degree

    def weakest(kept: np.ndarray) -> float:
        jac = moved[:, kept].reshape(len(columns), -1).T
        return float(np.linalg.svd(jac, compute_uv=False)[-1]) if jac.shape[0] >= len(columns) else 0.0

    if weakest(seen & ~image.unseen) * UNDETERMINED_DEG >= floor_px:
        return False
    return weakest(np.broadcast_to(seen, image.unseen.shape)) * UNDETERMINED_DEG >= floor_px


def _without_lost(q: np.ndarray, row: np.ndarray, kin, image: _kernels.Image, bounds: _kernels.Bounds,
                  rig: Rig, params: FitParams, eps: float,
                  unexplained: Callable[[np.ndarray, np.ndarray], bool] | None = None) -> np.ndarray | None:
    """A part's warm start ``row`` (d,) refined within ``bounds`` on its detections
    ``image`` (``_kernels.Image``, the projections its ``unseen`` marks left out) without
    its projections that look hidden as well, where that reaches :data:`WARM_EPS_FACTOR`
    times ``eps`` (already shrunk for ``image.unseen``) shrunk in proportion again, else
    None. Hidden: farther than the empty-view penalty from every blob at ``q`` (d,), the
    warm start refined with them (``_kernels._lost_markers``); at most
    :data:`MAX_LOST_SHARE` of the part's compared projections, and those left in two views
    (:func:`warm_start`), else None.

    Why: a marker hidden from one camera (a leg in front of it) is charged its distance to
    some other blob and keeps the part above 2 ε however right the warm start is, so with
    occluded markers almost every part ran SA in every image. Why it is safe: the
    projections left must still be explained at 0.5 px each (2 ε), which a posture in
    another basin is not in the views that see its markers, and a posture that only moves
    the hidden marker (a flip about the axis of the segment before it) is still offered as
    an alternative (``core.fit``). Where a marker merely slid (skin), it is within the
    penalty and nothing is left out.

    Nor where a DOF would be left placed in too few views (:func:`_left_in_too_few_views`):
    a marker compared in one view can slide along that camera's ray, and one compared in
    none places nothing, so a DOF that only such markers place (a tarsus, for its claw) is
    free in the refinement without them. A free-walking fly's warm start, refined, had its
    claw on the tibia-tarsus joint's blob in one of three views and off its blobs in the
    other two; left to that view, it stood in for SA with the tarsus at its range limit,
    32° off, and the next image's warm start carried it on.

    Nor where ``unexplained`` says a marker left out as hidden has unexplained blobs that
    meet in space in three of the views that leave it out (:func:`_hidden_marker_triangulated`):
    re-analysed, the free fly filmed at 50 Hz kept a hind leg 36° off that way, `ok`."""
    unseen, start = image.unseen, image.start
    if (without := left_out_with_lost(q, kin, rig, image)) is None:
        return None
    lost = without & ~unseen if unseen.size else without  # those left out as hidden
    if _left_in_too_few_views(lost, q, kin, image):
        return None
    compared = compared_count(unseen, start, len(kin.marker_joint))
    hidden = int(np.count_nonzero(lost))
    refined = _kernels.refine(np.ascontiguousarray(row), bounds, kin, rig.arrays,
                              image._replace(unseen=without), float(params.anneal.huber_px), WARM_STEPS,
                              _kernels.NO_TARGETS)
    value = part_objective(refined, kin, image.det, start, without, rig, params, image.offset)
    if value >= WARM_EPS_FACTOR * eps * (1.0 - hidden / compared):
        return None
    if unexplained is not None and unexplained(refined, lost):
        return None
    return refined


def _one_left_out(tried: tuple[np.ndarray, float, bool], part: Part, kin, points: np.ndarray,
                  start: np.ndarray, model: KinematicModel, rig: Rig, params: FitParams, eps: float,
                  off: np.ndarray, unseen: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """A part's warm start that did not stand in for SA (``tried``, after
    :func:`_reshared_warm_start`), refined again without its one projection farthest from a
    blob, standing in where that reaches :data:`WARM_EPS_FACTOR` times its ``eps`` shrunk in
    proportion to what is left out (with ``unseen`` (V, m)); ``tried`` otherwise. Only where
    the part has detections in three or more views, that projection lies within the
    empty-view penalty of a blob, every DOF moving it still moves markers compared in two
    views (:func:`_left_in_too_few_views`) and leaving it out frees no direction
    (:func:`_freed_by_leaving_out`), and the rest reach 2 ε already before the refinement
    (under sliding skin they do not, and the refinement would be spent).

    Why: a glint off the cuticle, or a ghost, merged with one marker's blob moves its
    centre by a pixel or two; the part's objective then misses 2 ε however right the warm
    start is, and SA ran to find the same posture (6-camera hexapod with 3 glints per view:
    23 of 375 warm starts missed, against 4 without glints; 21 of them reached 2 ε without
    their worst projection). Why it is safe: the other projections, in three views or more,
    must still be explained at 2 ε, which a posture in another basin is not. Not with two
    views: a marker left to one slides along its ray, and a depth flip explains most
    projections alike. Last, after the blobs shared or flagged merged are left out
    (:func:`_reshared_warm_start`), which leaves out all of them where two blobs moved."""
    seen = seen_views(start)
    if not params.refine or np.count_nonzero(seen) < 3:
        return tried
    image = kernel_image(points, start, params, off, unseen)
    q = tried[0]
    if (far := _farthest_projection(q, kin, rig, image)) is None:
        return tried
    left = image.unseen.copy() if image.unseen.size else np.zeros((len(seen), len(part.markers)), bool)
    left[far] = True
    if _left_in_too_few_views(left, q, kin, image) or _freed_by_leaving_out(
            q, model.rotational[part.dofs], kin, rig, image._replace(unseen=left),
            params.alternative_tolerance_px):
        return tried
    compared = len(part.markers) * np.count_nonzero(seen)
    reach = WARM_EPS_FACTOR * eps * (1.0 - np.count_nonzero(left) / compared)
    if part_objective(q, kin, points, start, left, rig, params, off) >= reach:
        return tried  # the rest are off too (sliding skin): no refinement would bring them under
    bounds = _kernels.Bounds(model.lower[part.dofs], model.upper[part.dofs])
    refined = _kernels.refine(np.ascontiguousarray(q), bounds, kin, rig.arrays, image._replace(unseen=left),
                              float(params.anneal.huber_px), WARM_STEPS, _kernels.NO_TARGETS)
    if part_objective(refined, kin, points, start, left, rig, params, off) >= reach:
        return tried
    return refined, part_objective(refined, kin, points, start, unseen, rig, params, off), True


def _farthest_projection(q: np.ndarray, kin, rig: Rig, image: _kernels.Image) -> tuple[int, int] | None:
    """(view, marker) of the projection of posture ``q`` (d,) (posed by ``kin``) farthest
    from its nearest blob among those ``image.unseen`` does not leave out, in views with
    detections, where that is within the empty-view penalty; else None."""
    proj = rig.project(_kernels.marker_positions_many(np.ascontiguousarray(q[None]), kin))[0]
    proj = proj + image.offset[:, None, :]
    best, where = -1.0, None
    for v in np.flatnonzero(seen_views(image.start)):
        gaps = np.sqrt(nearest_detection(proj[v], image.det[image.start[v]:image.start[v + 1]])[1])  # (m,)
        if image.unseen.size:
            gaps[image.unseen[v]] = -1.0
        m = int(np.argmax(gaps))
        if gaps[m] > best:
            best, where = float(gaps[m]), (int(v), m)
    return where if 0.0 < best <= image.penalty else None


def _left_in_too_few_views(lost: np.ndarray, q: np.ndarray, kin, image: _kernels.Image) -> bool:
    """Whether, once a part's ``lost`` (V, m) projections are left out, some DOF of posture
    ``q`` (d,) (posed by ``kin``) that moves a lost marker moves markers compared in fewer
    than two views with detections where there are three or more, or in none where there
    are two or one.

    Per DOF, not per marker: a knee marker hidden from two of three cameras is still placed
    by the shank and foot markers that move with the same DOFs, and leaving it out keeps
    the warm start; asking two views of every such marker sent those warm starts to SA for
    the same angles (docs/BENCH_SUBJECTS.md, the free fly). With two cameras a
    hidden marker is left to one view, as it is by the objective anyway. Projections
    ``image.unseen`` leaves out (next to another part's marker) count as compared:
    :func:`_may_leave_out` judged them, and a fusion places them. (:func:`warm_start` asks
    the same of those projections themselves, passed as ``lost``.)"""
    seen = seen_views(image.start)
    compared = seen[:, None] & ~lost  # (V, m)
    needed = 2 if np.count_nonzero(seen) >= 3 else 1
    if (np.count_nonzero(compared, axis=0)[lost.any(axis=0)] >= needed).all():
        return False  # each lost marker is compared in enough views, so each DOF moving it is
    moved = _moved_markers(q, kin)  # (d, m)
    for dof in np.flatnonzero(moved[:, lost.any(axis=0)].any(axis=1)):  # DOFs moving a lost marker
        if np.count_nonzero(compared[:, moved[dof]].any(axis=1)) < needed:
            return True
    return False


def _moved_markers(q: np.ndarray, kin) -> np.ndarray:
    """(d, m) bool: which of a part's markers each DOF moves at posture ``q`` (d,) (posed by
    ``kin``), from the Jacobian of the marker positions (``core.identifiability.marker_jacobian``,
    every column in model units per step: only which markers a DOF moves is read, against the
    most it moves any): a marker on a rotation's axis, or above its joint, is not moved by it."""
    def positions(postures: np.ndarray) -> np.ndarray:
        return _kernels.marker_positions_many(np.ascontiguousarray(postures), kin)

    d = len(q)
    jac = marker_jacobian(positions, q, np.zeros(d, dtype=bool), 1.0)  # (3m, d)
    speed = np.linalg.norm(jac.T.reshape(d, -1, 3), axis=2)  # (d, m)
    return speed > 1e-6 * np.maximum(speed.max(axis=1, keepdims=True), 1e-300)


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
    same way. A part whose kept posture reaches twice its ε skips SA (SA stops there) and is
    settled. So is a part whose kept posture, refined, is below its ceiling from the
    sequence's typical objective ``typical`` (pixels, NaN for none; :func:`typical_ceilings`):
    it is kept as a warm start under its ceiling is, without a search. ``settled`` is True
    when every part is (``core.fit.reanalyse_image`` settles an
    image whose attempt is not lower than the kept posture as well). A kept posture that
    reaches it only with a marker left out as hidden is searched where that marker's
    unexplained blobs meet in space (:func:`_hidden_marker_triangulated`).
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
        unexplained = None if keep is None else partial(_hidden_marker_triangulated, q, part, points,
                                                         start, model, rig, params, off)
        tried = warm_start(part.dofs, kin, points, start, warm, model, rig, params, eps, off, unseen,
                           ceiling, unexplained)
        if tried is not None and not tried[2] and warm is not None:
            tried = _reshared_warm_start(part, tried, np.where(done, q, warm[0]), kin, points, start, model,
                                         rig, tree, params, eps, off, unseen, ceiling, unexplained)
        if tried is not None and not tried[2] and warm is not None:
            tried = _one_left_out(tried, part, kin, points, start, model, rig, params, eps, off, unseen)
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
            if not candidates:
                candidates.append(triangulate(det, rig=rig, offsets=off))
            proposed = epipolar_start(part, rotation, origin, candidates[0], points, start, model,
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
            if _explained_without(part, q, contested[:, part.markers], det, points, start, model, rig,
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


def _reshared_warm_start(part: Part, tried: tuple[np.ndarray, float, bool], posture: np.ndarray, kin,
                         points: np.ndarray, start: np.ndarray, model: KinematicModel, rig: Rig, tree: Tree,
                         params: FitParams, eps: float, off: np.ndarray, unseen: np.ndarray,
                         ceiling: Callable[[], float] | None,
                         unexplained: Callable[[np.ndarray, np.ndarray], bool] | None,
                         ) -> tuple[np.ndarray, float, bool]:
    """A part's warm start that did not stand in for SA (``tried``, from :func:`warm_start`)
    tried again with more of its projections left out: those next to another part's marker
    (:func:`shared_projections`) where the part stands at its refined warm start and the
    other parts at ``posture`` (D,) (where this attempt fitted them, else at the previous
    image's posture), and those on a detection the detector flags as merged markers
    (:func:`on_merged_blobs`), where :func:`_may_leave_out` allows them and ``unseen``
    (V, m) does not mark them all already; and with the blobs of other parts' markers at
    ``posture`` never charged as unexplained (:func:`_explained_elsewhere`). ``tried`` where
    neither applies.

    Why: the shared projections are read at the previous image's posture, and legs that
    moved together since then leave a marker fused with another leg's in some view. The
    fused blob lies pixels from both, no posture of the part alone explains it, and a
    warm start on the truth missed twice its ε by a pixel: SA then ran to its patience,
    the triangulated start and the conflict sweeps after it, 0.2 s of a 6-camera hexapod
    image instead of 5 ms, to end where the warm start was. The same checks judge the
    retry (:func:`warm_start`): the projections left must be explained at twice ε shrunk in
    proportion, which a leg in another basin, pixels off in the views that do not fuse it,
    is not; and :func:`_may_leave_out` must allow the projections left out."""
    at = posture.copy()
    at[part.dofs] = tried[0]
    near = max(float(params.fusion_px), CLAIM_PX)
    again = in_seen_views(shared_projections(at, model, rig, tree, params, off)[part.name], start)
    again |= on_merged_blobs(rig.project(model.marker_positions(at)[part.markers]) + off[:, None, :],
                             points, start, near)
    before = in_seen_views(unseen, start) if unseen.size else np.zeros_like(again)
    again |= before
    fused = _fusions(at, part, model, rig, points, start, off, near)
    more = np.count_nonzero(again) > np.count_nonzero(before) and _may_leave_out(again, start, fused)
    flagged = _explained_elsewhere(points, start, at, part, model, rig, params, off)
    if not more and not flagged[:, 3].any():
        return tried
    retried = warm_start(part.dofs, kin, flagged, start, at[None], model, rig, params, eps, off,
                         again if more else unseen, ceiling, unexplained)
    return tried if retried is None else retried


def _explained_elsewhere(points: np.ndarray, start: np.ndarray, posture: np.ndarray, part: Part,
                         model: KinematicModel, rig: Rig, params: FitParams, off: np.ndarray) -> np.ndarray:
    """Detections ``points`` (n, 3) grouped at ``start`` with a fourth column (``_kernels.Image``):
    1.0 where the nearest detection of a marker outside ``part``, at ``posture`` (D,), lies
    within half the fusion distance (at least :data:`CLAIM_PX`) of it: a blob that marker
    forms, alone or merged with another, which ``part``'s objective must not charge as
    unexplained.

    Why: where two of a part's own markers merge into one blob, the objective charges every
    unclaimed detection within the fusion distance (2 marker diameters) of them: the blob a
    wrong posture that squeezes two markers onto one would leave (``_kernels._unexplained``).
    A part's detections include its neighbours' blobs, which no marker of the part claims.
    With 9 px markers the 6-camera hexapod's legs, on the truth, were charged 12-20 px for a
    neighbouring leg's blob next to their own merged pair, above twice their ε, and ran SA
    at 29 ms instead of standing in from the warm start."""
    others = outside(part, len(model.markers))
    proj = rig.project(model.marker_positions(posture)[others]) + off[:, None, :]  # (V, M - m, 2)
    radius = max(0.5 * float(params.fusion_px), CLAIM_PX)
    out = np.zeros((len(points), 4))
    out[:, :3] = points[:, :3]
    for v in np.flatnonzero(seen_views(start)):
        a, b = start[v], start[v + 1]
        nearest, d2 = nearest_detection(proj[v], points[a:b])
        out[a + nearest[d2 <= radius * radius], 3] = 1.0
    return out


def _hidden_marker_triangulated(posture: np.ndarray, part: Part, points: np.ndarray, start: np.ndarray,
                                model: KinematicModel, rig: Rig, params: FitParams, off: np.ndarray,
                                q: np.ndarray, hidden: np.ndarray) -> bool:
    """Whether a marker of ``part`` at ``q`` (d,), the rest of the model at ``posture`` (D,),
    left out as hidden in :data:`HIDDEN_SEEN_VIEWS` or more views (``hidden`` (V, m)), has
    a 3D point there after all: blobs of that many of those views among ``points`` (N, 3)
    grouped at ``start`` (V + 1,) (the part's reach) that no marker projection explains
    (none within half the fusion distance, at least :data:`CLAIM_PX`: where a fusion of two
    markers puts its blob) and that meet in space (``core.triangulate``).

    A marker hidden from a camera leaves no blob in its view. Unexplained blobs of three
    such views that meet in space are most likely the marker itself, with the part in
    another basin, and the part is searched. Two views are not enough: any two blobs on
    each other's epipolar lines meet, and in the 3-camera fly with 10 % of projections
    hidden, every pair found (3 images) belonged to markers truly hidden there (ghosts, or
    blobs of another leg in another basin); searching those legs again changed 5 images
    for the worse. Asked in a re-analysis only (:func:`refit_tree`), where every other part
    is fitted: in a first attempt the parts not yet fitted stand at the previous image's
    posture, pixels off their blobs."""
    markers = np.flatnonzero(np.count_nonzero(hidden, axis=0) >= HIDDEN_SEEN_VIEWS)
    if len(markers) == 0:
        return False
    at = posture.copy()
    at[part.dofs] = q
    proj = rig.project(model.marker_positions(at)) + off[:, None, :]  # (V, M, 2)
    explained = explained_blobs(proj, points, start, max(0.5 * float(params.fusion_px), CLAIM_PX))
    unexplained = [points[a:b, :2][~explained[a:b]] for a, b in pairwise(start)]
    for m in markers:
        views = [u if hidden[v, m] else u[:0] for v, u in enumerate(unexplained)]
        found = triangulate(Detections.from_views(views), rig=rig, offsets=off)
        if np.any(found.n_views >= HIDDEN_SEEN_VIEWS):
            return True
    return False


def _may_leave_out(left_out: np.ndarray, start: np.ndarray, fused: np.ndarray | None = None) -> bool:
    """Whether a part's warm start may be judged without its projections ``left_out`` (V, m)
    (views with detections grouped at ``start`` only): at most :data:`MAX_LOST_SHARE` of its
    compared projections, and every marker with a projection left out still compared in
    two views, so that it keeps its depth (with two cameras, a marker left to one view can
    slide along that camera's ray: a leg of the 2-camera hexapod with 10 % of its markers
    hidden went 5° off in several DOFs without this), except where the projection left out
    is ``fused`` (V, m) (:func:`_fusions`: its blob is where it and another part's marker
    merge, which places it as well as a blob of its own would). Fused projections may take
    the left-out share to twice :data:`MAX_LOST_SHARE`, no more: a leg lying on another
    leg's markers would look fused everywhere."""
    seen = seen_views(start)
    unexplained = left_out if fused is None else left_out & ~fused
    compared = seen[:, None] & ~left_out
    limit = MAX_LOST_SHARE * left_out.shape[1] * np.count_nonzero(seen)
    return bool(np.count_nonzero(unexplained) <= limit and np.count_nonzero(left_out) <= 2 * limit
                and (compared.sum(axis=0)[unexplained.any(axis=0)] >= 2).all())


def _fusions(q: np.ndarray, part: Part, model: KinematicModel, rig: Rig, points: np.ndarray,
             start: np.ndarray, off: np.ndarray, near: float) -> np.ndarray:
    """(V, m) bool: the projections of ``part``'s markers at posture ``q`` (D,) that lie
    within ``near`` px of a marker of another part whose midpoint with it is within
    :data:`FUSED_PX` of a detection of the view (``points`` (N, 3) grouped at ``start``):
    the two markers seen as one blob, where a merged blob's centroid lies.

    Two legs whose joints touch (the hexapod's femur-tibia joints, seed 3, images 65 and 75)
    fuse in every view; leaving those projections out for being shared would leave the
    marker in no view, yet each blob is where the two markers' fusion puts it."""
    proj = rig.project(model.marker_positions(q)) + off[:, None, :]  # (V, M, 2)
    others = outside(part, len(model.markers))
    out = np.zeros((len(start) - 1, len(part.markers)), dtype=bool)
    for v in np.flatnonzero(seen_views(start)):
        mine, theirs = proj[v, part.markers], proj[v, others]
        gap = np.linalg.norm(mine[:, None] - theirs[None], axis=2)  # (m, M - m)
        i, j = np.nonzero(gap <= near)
        if len(i) == 0:
            continue
        d2 = nearest_detection(0.5 * (mine[i] + theirs[j]), points[start[v]:start[v + 1]])[1]
        out[v, i[d2 <= FUSED_PX ** 2]] = True
    return out


def _explained_without(part: Part, q: np.ndarray, left_out: np.ndarray, det: Detections, points: np.ndarray,
                       start: np.ndarray, model: KinematicModel, rig: Rig, params: FitParams, off: np.ndarray,
                       views_seen: int, shared: np.ndarray) -> bool:
    """Whether branch ``part`` at posture ``q`` (D,), refined as a warm start
    (:func:`warm_start`), explains the detections ``points`` grouped at ``start`` (those of
    the image ``det`` no other branch claims) within twice its ε without its projections
    ``left_out`` (V, m) (those on a detection another branch claims too) and ``shared``
    (V, m) (next to another part's marker, :func:`shared_projections`), where
    :func:`_may_leave_out` allows it (fusions read on all of ``det``: the blob two branches
    share is not among the free ones).

    Why: the conflict sweep searches such a branch again by SA on those detections, for a
    branch on its neighbour's blobs. A branch in the right basin whose marker projects onto
    the same blob as a neighbour's in one view (two markers nearly coincide, and the blob is
    no larger than one) explains everything else: its search ends worse and is thrown away,
    0.1 s of a 6-camera hexapod image. A branch in another basin is pixels off in the other
    views as well, and is searched."""
    if shared.size:
        left_out = left_out | shared
    left_out = in_seen_views(left_out, start)
    near = max(float(params.fusion_px), CLAIM_PX)
    fused = _fusions(q, part, model, rig, det.kernel_points, det.start, off, near)
    if not _may_leave_out(left_out, start, fused):
        return False
    kin = part.at(*base_frame(q, model, part))
    tried = warm_start(part.dofs, kin, points, start, q[None], model, rig, params,
                       part_eps(part, params, views_seen), off, left_out)
    return tried is not None and tried[2]


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
    error = _kernels.posture_error(q, kin, views, image._replace(fuse_px=0.0))
    return q, float(error), float(value)


def refine_without_lost(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                        params: FitParams, off: np.ndarray
                        ) -> tuple[np.ndarray, float, float, np.ndarray] | None:
    """A whole posture ``q`` (D,) refined by :data:`JOINT_STEPS` LM steps on ``det`` without
    the projections that look hidden at ``q`` itself: (posture, plain Eq. 5 error, objective
    as :func:`refine_whole` reports it, those projections (V, M) bool); None
    where none look hidden, more than :data:`MAX_LOST_SHARE` of the compared projections do,
    or those left do not lie in two views (:func:`judged_in_two_views`).

    Hidden as :func:`left_out_with_lost` reads them, as :func:`_without_lost` does for a
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
    error = _kernels.posture_error(refined, model.arrays, rig.arrays, image._replace(fuse_px=0.0))
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
                error = _kernels.posture_error(whole, model.arrays, views, image._replace(fuse_px=0.0))
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
