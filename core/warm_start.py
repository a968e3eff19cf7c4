"""A part's warm start: the previous image's posture, refined, standing in for SA.

Within a chunk, each part first tries the previous image's posture (:func:`warm_start`):
refined on the part's detections, it replaces the part's SA where it reaches twice the
part's ε or, under sliding skin markers, the part's level in the previous image plus what
its residual cannot tell apart (:func:`core.ceilings.warm_ceilings`), or on its other
projections with those of markers that look hidden left out (:func:`_without_lost`). One
that misses is tried again after the other branches on its base are fitted, without the
projections this image's postures put on another part's marker or a merged blob
(:func:`reshared_warm_start`); when every part came from a warm start the joint refinement
takes :data:`core.treefit.WARM_JOINT_STEPS` steps: at 50-200 Hz most parts of most images
skip SA (figures in docs/BENCH_SUBJECTS.md).

A warm start that still misses, with three views or more, is tried once more without its
one projection farthest from a blob (:func:`one_left_out`). The same rules judge whether a
branch in a conflict is searched again at all (:func:`explained_without`, ``core.claims``)
and, in a re-analysis, whether a marker left out as hidden has unexplained blobs that meet
in space (:func:`hidden_marker_triangulated`).

Here: what ``core.treefit`` asks of a part's warm start, in the order it asks it, and why
each rule is safe; the levels and ceilings a warm start is held to are ``core.ceilings``',
the blobs other parts claim ``core.claims``'.
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import pairwise
from typing import TYPE_CHECKING

import numpy as np

from core import _kernels
from core.ceilings import (
    MAX_LOST_SHARE,
    judged_in_two_views,
    left_out_with_lost,
    under_ceiling,
)
from core.claims import CLAIM_PX, FUSED_PX, explained_blobs, on_merged_blobs, shared_projections, within_reach
from core.error import Detections, nearest_detection
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
)
from core.rig import Rig
from core.tree import Part, Tree
from core.triangulate import ray_meetings, triangulate
from core.undetermined import UNDETERMINED_DEG

if TYPE_CHECKING:
    from core.fit import FitParams

__all__ = ["HIDDEN_SEEN_VIEWS", "WARM_EPS_FACTOR", "WARM_STEPS", "explained_without",
           "hidden_marker_triangulated", "one_left_out", "reshared_warm_start", "warm_start"]

WARM_STEPS = 10  # LM steps refining the previous image's posture of a part (a warm start)
WARM_EPS_FACTOR = 2.0  # a warm start stands in for SA within this many times the part's ε
HIDDEN_SEEN_VIEWS = 3  # unexplained blobs of this many views meeting in space: a marker not hidden
REACHED_SHARE = 0.25  # a point a lost marker may be at lies this share of its arm off its arm's length
MAX_REACHED = 3  # such points tried per marker, nearest first


def warm_start(dofs: np.ndarray, kin, points: np.ndarray, start: np.ndarray, warm: np.ndarray | None,
               model: KinematicModel, rig: Rig, params: FitParams, eps: float, off: np.ndarray,
               unseen: np.ndarray = _kernels.NO_UNSEEN,
               ceiling: Callable[[], float] | None = None,
               unexplained: Callable[[np.ndarray, np.ndarray], bool] | None = None,
               ) -> tuple[np.ndarray, float, bool] | None:
    """The warm starts ``warm`` (k, D), each one's posture of the DOFs ``dofs`` (a part posed
    by ``kin``) refined on detections ``points`` (N, 3) grouped at ``start`` (V + 1,) by
    :data:`WARM_STEPS` LM steps: (posture (d,), objective in pixels, whether it stands in
    for SA) of the first that reaches :func:`_stand_in_limit` (twice ``eps``, SA's stop), or
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
    sequence's typical objective instead (:func:`core.ceilings.typical_ceilings`).

    ``unexplained(q, hidden)``, where given (a re-analysis), says whether a marker the part
    at posture ``q`` (d,) leaves out as hidden (``hidden`` (V, m)) has unexplained blobs in
    those views that meet in space (:func:`hidden_marker_triangulated`); such a warm start
    does not stand in (:func:`_without_lost`).

    ``unseen`` (V, m) bool marks projections next to another part's marker
    (:func:`shared_projections`): they are left out of the refinement and of the objective
    (:func:`part_objective`), and the limit shrinks in proportion (:func:`_stand_in_limit`).
    Such a blob is two markers fused, off each by pixels, which no posture of this part alone
    explains: left in, it keeps a leg that fits everywhere else above ε (the joint
    refinement reads it as fused). They are read at the posture the warm start came from,
    so a warm start judged without them must leave every DOF placed in two views (one with
    two cameras, :func:`_left_in_too_few_views`): at 50 Hz the free fly's hind claw, next
    to another leg's marker in the previous image, was left out in enough views to free
    the tarsus, and the warm start stood in 25° off. Nor may leaving them out free a
    direction that no single DOF shows, two DOFs turning against each other
    (:func:`_freed_by_leaving_out`). The projections that lie beyond their view's edge at the
    refined posture are judged the same way (:func:`_beyond_left_out`): their 5 px each
    kept a leg that walked out of a frame above ε in every image, and SA searched it again.

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
        left = _beyond_left_out(q, kin, rig, image, unseen)
        judged = image._replace(unseen=left)
        seen_value = (value if left is unseen
                      else part_objective(q, kin, points, start, left, rig, params, off))
        if (seen_value < _stand_in_limit(eps, left, start) and judged_in_two_views(left, start) and not (
                left.any() and (_left_in_too_few_views(left, q, kin, judged)
                                or _freed_by_leaving_out(q, rot, kin, rig, judged,
                                                         params.alternative_tolerance_px)))):
            return q, value, True
        if params.refine and views and (seen := _without_lost(q, row[dofs], kin, image, bounds, rig,
                                                              params, eps, unexplained)) is not None:
            return seen, part_objective(seen, kin, points, start, unseen, rig, params, off), True
        if best is None or value < best[1]:
            best = (q, value, False)
    if best is not None and ceiling is not None and views:
        best = (best[0], best[1], under_ceiling(best[0], kin, rig, image, params, ceiling()))
    return best


def _beyond_left_out(q: np.ndarray, kin, rig: Rig, image: _kernels.Image, unseen: np.ndarray) -> np.ndarray:
    """``unseen`` (V, m), with the projections of a part's posture ``q`` that lie beyond
    their view's edge (``_kernels.beyond_edges``) left out too: a warm start is judged on
    what the cameras could see, as it is without the blobs it shares."""
    beyond = _kernels.beyond_edges(q, kin, rig.arrays, image)
    if not beyond.any():
        return unseen
    return in_seen_views(unseen | beyond if unseen.size else beyond, image.start)


def _stand_in_limit(eps: float, left_out: np.ndarray, start: np.ndarray) -> float:
    """Pixels under which a part's objective, judged without its projections ``left_out``
    (V, m) bool (or an empty array: none), lets its warm start stand in for SA:
    :data:`WARM_EPS_FACTOR` times its ε ``eps`` (SA's stop over all its projections into the
    views with detections grouped at ``start``), times the share of those projections
    judged. ε counts per projection (``core.part_objective``), so a part judged on fewer is
    held to as much per projection.

    >>> round(_stand_in_limit(2.0, np.array([[True, False], [False, False]]), np.array([0, 3, 5])), 6)
    3.0
    """
    if not left_out.size:
        return WARM_EPS_FACTOR * eps
    seen = seen_views(start)
    judged = left_out.shape[1] * int(np.count_nonzero(seen))
    return WARM_EPS_FACTOR * eps * (1.0 - np.count_nonzero(left_out & seen[:, None]) / max(judged, 1))


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
    its projections that look hidden as well, where that reaches :func:`_stand_in_limit`
    without both, else None; where such a marker is left to one view, a posture that
    explains it again is preferred (:func:`_lost_blob_reached`). Hidden: farther than the
    empty-view penalty from every blob at ``q`` (d,), the warm start refined with them
    (``_kernels._lost_markers``); at most
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
    meet in space in three of the views that leave it out (:func:`hidden_marker_triangulated`):
    re-analysed, the free fly filmed at 50 Hz kept a hind leg 36° off that way, `ok`."""
    unseen, start = image.unseen, image.start
    if (without := left_out_with_lost(q, kin, rig, image)) is None:
        return None
    lost = without & ~unseen if unseen.size else without  # those left out as hidden
    if _left_in_too_few_views(lost, q, kin, image):
        return None
    refined = _kernels.refine(np.ascontiguousarray(row), bounds, kin, rig.arrays,
                              image._replace(unseen=without), float(params.anneal.huber_px), WARM_STEPS,
                              _kernels.NO_TARGETS)
    value = part_objective(refined, kin, image.det, start, without, rig, params, image.offset)
    if value >= _stand_in_limit(eps, without, start):
        return None
    if unexplained is not None and unexplained(refined, lost):
        return None
    reached = _lost_blob_reached(refined, lost, kin, image, bounds, rig, params, eps)
    return refined if reached is None else reached


def _lost_blob_reached(q: np.ndarray, lost: np.ndarray, kin, image: _kernels.Image, bounds: _kernels.Bounds,
                       rig: Rig, params: FitParams, eps: float) -> np.ndarray | None:
    """A posture of a part that explains every projection on ``image`` but those
    ``image.unseen`` leaves out, within :func:`_stand_in_limit`, found from its
    warm start ``q`` (d,) (posed by ``kin``, refined without its ``lost`` (V, m) projections)
    where a marker left out as lost is compared in one view at most; else None.

    Looked for at the points where unexplained blobs (none of the part's projections within
    half the fusion distance, at least ``CLAIM_PX``) of two views meet
    (``core.triangulate.ray_meetings``) at the marker's distance from the joint it turns
    about (within :data:`REACHED_SHARE` of it), nearest the marker first, at most
    :data:`MAX_REACHED`: the marker moved there by inverse kinematics, the others held, then
    refined on the image.

    Why: left to one view, a marker slides along that camera's ray, and a segment that only
    it places can fold onto its joint's blob there, pixels off its own blob in the other
    view, where it looks hidden and is left out. With two cameras the rest still reach 2 ε
    (:func:`_left_in_too_few_views` asks one view of each DOF there): a fly's hind tarsus
    stood in for SA 26° off, its claw's blobs in both views unexplained, and the image ended
    `ok` 17° off (docs/BENCH_SUBJECTS.md, stop 50). Asking two views of each DOF with two
    cameras instead sent the warm starts of markers truly hidden to SA, which lost images
    (the 2-camera free fly with 10 % hidden: 46.7 → 43.3 % within 5°)."""
    seen = seen_views(image.start)
    left = lost | image.unseen if image.unseen.size else lost
    single = np.flatnonzero(lost.any(axis=0) & (np.count_nonzero(seen[:, None] & ~left, axis=0) <= 1))
    if not single.size:
        return None
    world = _kernels.marker_positions_many(np.ascontiguousarray(q[None]), kin)[0]  # (m, 3)
    proj = rig.project(world) + image.offset[:, None, :]  # (V, m, 2)
    unexplained = ~explained_blobs(proj, image.det, image.start, max(0.5 * float(params.fusion_px), CLAIM_PX))
    joints = _joint_origins(q, kin)
    limit = _stand_in_limit(eps, image.unseen, image.start)
    for m in single:
        pivot = _pivot(world[m], int(kin.marker_joint[m]), joints, kin.parent)
        arm = float(np.linalg.norm(world[m] - pivot))
        # Blobs a point within the arm of the pivot may project onto, the arm widened by
        # core.tree.REACH_MARGIN (1.25, no less than 1 + REACHED_SHARE), as a branch's reach is.
        reachable = unexplained & within_reach(image.det, image.start, rig, pivot[None], np.array([arm]),
                                               image.offset)[0]
        views = [image.det[a:b, :2][reachable[a:b]] for a, b in pairwise(image.start)]
        if not any(len(views[v]) for v in np.flatnonzero(lost[:, m])):
            continue  # no unexplained blob the marker could reach in a view it looks hidden in
        points = ray_meetings(Detections.from_views(views), rig=rig, offsets=image.offset)
        near = np.abs(np.linalg.norm(points - pivot, axis=1) - arm) <= REACHED_SHARE * arm
        for point in points[near][np.argsort(np.linalg.norm(points[near] - world[m], axis=1))][:MAX_REACHED]:
            moved = _moved_to(q, m, point, world, kin, image, bounds, rig, params)
            if part_objective(moved, kin, image.det, image.start, image.unseen, rig, params,
                              image.offset) < limit:
                return moved
    return None


def _moved_to(q: np.ndarray, m: int, point: np.ndarray, world: np.ndarray, kin, image: _kernels.Image,
              bounds: _kernels.Bounds, rig: Rig, params: FitParams) -> np.ndarray:
    """A part's posture ``q`` (d,) with its marker ``m`` moved to ``point`` (3,) by inverse
    kinematics (its other markers held at ``world`` (m, 3)), then refined on ``image``."""
    targets = world.copy()
    targets[m] = point
    moved = _kernels.refine(np.ascontiguousarray(q), bounds, kin, rig.arrays, image, 1e9, WARM_STEPS, targets)
    return _kernels.refine(moved, bounds, kin, rig.arrays, image, float(params.anneal.huber_px), WARM_STEPS,
                           _kernels.NO_TARGETS)


def _pivot(marker: np.ndarray, joint: int, origins: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """(3,) the origin of the nearest joint at or above ``joint`` (the one a marker at
    ``marker`` (3,) is attached to) that lies apart from the marker: the point it turns about."""
    while parent[joint] >= 0 and np.linalg.norm(origins[joint] - marker) <= 1e-9:
        joint = int(parent[joint])
    return origins[joint]


def _joint_origins(q: np.ndarray, kin) -> np.ndarray:
    """(J, 3) the world origin of every joint of a part at posture ``q`` (d,), posed by ``kin``."""
    frames = np.empty(_kernels.FRAME * len(kin.parent))
    _kernels.joint_frames(np.ascontiguousarray(q), kin, frames, np.empty(2 * len(q)))
    return frames.reshape(-1, _kernels.FRAME)[:, 9:12].copy()


def one_left_out(tried: tuple[np.ndarray, float, bool], part: Part, kin, points: np.ndarray,
                 start: np.ndarray, model: KinematicModel, rig: Rig, params: FitParams, eps: float,
                 off: np.ndarray, unseen: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """A part's warm start that did not stand in for SA (``tried``, after
    :func:`reshared_warm_start`), refined again without its one projection farthest from a
    blob, standing in where that reaches :func:`_stand_in_limit` without it and ``unseen``
    (V, m); ``tried`` otherwise. Only where
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
    (:func:`reshared_warm_start`), which leaves out all of them where two blobs moved."""
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
    reach = _stand_in_limit(eps, left, start)
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


def reshared_warm_start(part: Part, tried: tuple[np.ndarray, float, bool], posture: np.ndarray, kin,
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
    retry (:func:`warm_start`): the projections left must be explained within
    :func:`_stand_in_limit`, which a leg in another basin, pixels off in the views that do not fuse it,
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


def hidden_marker_triangulated(posture: np.ndarray, part: Part, points: np.ndarray, start: np.ndarray,
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
    for the worse. Asked in a re-analysis only (:func:`core.treefit.refit_tree`), where every other part
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


def explained_without(part: Part, q: np.ndarray, left_out: np.ndarray, det: Detections, points: np.ndarray,
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
