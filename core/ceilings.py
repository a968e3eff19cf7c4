"""A part's level and its ceiling: how far above its ε a warm start may stand in for SA.

Under sliding skin markers no posture of a part reaches twice its ε, and the level of its
minimum is the markers' slide, which varies slowly from image to image. A warm start
(``core.warm_start``) then stands in for SA where its level, its objective with the
projections that look hidden charged the empty-view penalty (:func:`_ceiling_level`), is
under the part's ceiling: the part's level in the previous image plus what a residual at
that level cannot tell apart (:func:`warm_ceilings`), or in a re-analysis the level the
sequence's typical objective gives it (:func:`typical_ceilings`). A warm start that missed
its ceiling as a slide does (:func:`missed_by_a_slide`) has its SA stop once as low as it
(``core.treefit``). Why each rule, and what went wrong without it, is in its function's
docstring (the ceiling's own in ``core.warm_start.warm_start``).

Which projections look hidden is read here as well (:func:`_lost`: farther than the
empty-view penalty from every blob of their view; at most :data:`MAX_LOST_SHARE` of a
part's, the rest in two views, :func:`left_out_with_lost`), since the level charges them;
the warm starts and ``core.treefit.refine_without_lost`` leave out the same ones.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from core import _kernels
from core.claims import reaches, shared_projections, subset
from core.error import Detections
from core.model import KinematicModel
from core.part_objective import (
    base_frame,
    in_seen_views,
    kernel_image,
    part_objective,
    seen_views,
    whole_image,
)
from core.rig import Rig
from core.tree import Part

if TYPE_CHECKING:
    from core.fit import FitParams

__all__ = ["MAX_LOST_SHARE", "SLIDE_FACTOR", "compared_count", "hidden_charge", "judged_in_two_views",
           "left_out_with_lost", "missed_by_a_slide", "typical_ceilings", "under_ceiling", "warm_ceilings"]

MAX_LOST_SHARE = 0.25  # of a part's projections, at most this share may look hidden in a warm start
SLIDE_FACTOR = 2.0  # a warm start under this many times its ceiling missed it by sliding markers


def left_out_with_lost(q: np.ndarray, kin, rig: Rig, image: _kernels.Image) -> np.ndarray | None:
    """The projections (V, m) bool to leave out of posture ``q`` (posed by ``kin``) on
    ``image``: those ``image.unseen`` marks, and those that look hidden, farther than the
    empty-view penalty from every blob of their view (``_kernels._lost_markers``). None
    where none look hidden, more than :data:`MAX_LOST_SHARE` of the compared projections
    do, or those left do not lie in two views (:func:`judged_in_two_views`)."""
    lost = _lost(q, kin, rig, image)
    return _left_out(lost, image) if lost.any() else None


def _left_out(lost: np.ndarray, image: _kernels.Image) -> np.ndarray | None:
    """The projections (V, m) bool a part's ``lost`` ones (:func:`_lost`) and those
    ``image.unseen`` marks leave out, or None where ``lost`` holds more than
    :data:`MAX_LOST_SHARE` of the compared projections or those left do not lie in two
    views (:func:`judged_in_two_views`)."""
    unseen, start = image.unseen, image.start
    if np.count_nonzero(lost) > MAX_LOST_SHARE * compared_count(unseen, start, lost.shape[1]):
        return None
    without = lost | unseen if unseen.size else lost
    return without if judged_in_two_views(without, start) else None


def _ceiling_level(q: np.ndarray, kin, rig: Rig, image: _kernels.Image, params: FitParams
                   ) -> tuple[float, int, bool]:
    """What a part's warm-start ceiling reads of its posture ``q`` (d,) posed by ``kin`` on
    ``image`` (:func:`warm_ceilings`, :func:`core.warm_start.warm_start`): (the objective, pixels, of its
    projections that do not look hidden (:func:`_lost`), how many look hidden, False) where
    the rest can judge the part (:func:`_left_out`); else (:func:`part_objective`, 0, True):
    most of its projections look hidden. Its level is the objective plus the empty-view
    penalty for each hidden projection, as a lost marker is charged.

    Why: the ceiling is the level of sliding skin markers. A hidden marker's distance to
    another blob (tens of pixels) would swamp it, and the next image's ceiling would let a
    leg in another basin stand in for SA. Where most of a part's projections look hidden,
    the previous image's posture is all that places it (a trunk with two of its three
    markers hidden), and the level stays on every projection."""
    lost = _lost(q, kin, rig, image)
    if (without := _left_out(lost, image)) is None:
        return (part_objective(q, kin, image.det, image.start, image.unseen, rig, params, image.offset),
                0, True)
    return (part_objective(q, kin, image.det, image.start, without, rig, params, image.offset),
            int(np.count_nonzero(lost)), False)


def hidden_charge(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, params: FitParams,
                  off: np.ndarray, beyond: int) -> float:
    """Pixels of the whole objective of posture ``q`` (D,) on ``det`` (view offsets ``off``
    (V, 2)) that what the image does not show costs: the empty-view penalty for each
    projection that looks hidden (:func:`_lost`: farther than the penalty from every blob of
    its view), for each of the ``beyond`` beyond its view's region (``core.error.outside_error``
    counts them) and for each marker of a view without detections, the least the objective
    charges each of those."""
    lost = np.count_nonzero(_lost(q, model.arrays, rig, whole_image(det, params, off)))
    empty = np.count_nonzero(~seen_views(det.start)) * len(model.markers)
    return float(params.empty_view_penalty_px) * (lost + beyond + empty)


def _lost(q: np.ndarray, kin, rig: Rig, image: _kernels.Image) -> np.ndarray:
    """(V, m) bool, the projections of posture ``q`` (posed by ``kin``) that look hidden on
    ``image``: farther than the empty-view penalty from every blob of their view
    (``_kernels._lost_markers``), in views with detections, not already left out by
    ``image.unseen``."""
    lost = in_seen_views(_kernels._lost_markers(q, kin, rig.arrays, image, image.penalty, True)[0],
                         image.start)
    return lost & ~image.unseen if image.unseen.size else lost


def warm_ceilings(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                  params: FitParams, off: np.ndarray) -> dict[str, float]:
    """Per part of ``model.tree`` (by name), the objective per compared marker projection
    below which its warm start stands in for SA in the next image (:func:`core.warm_start.warm_start`):
    the part's objective at this image's fitted posture ``q`` (D,) on detections ``det``
    with its projections that look hidden charged the empty-view penalty
    (:func:`_ceiling_level`), plus what a residual at that level cannot tell apart
    (:func:`_ceiling`), over its compared projections (markers × views with detections
    within its reach, less those next to another part's marker, :func:`shared_projections`).

    The level is that of this image's first fit (its parts searched by SA, or warm started
    under this image's own ceilings); per projection, so that a marker next to another
    part's in the next image does not move it.

    NaN (no ceiling: the next image searches the part) for a branch most of whose
    projections look hidden, its level then read on every projection (:func:`_ceiling_level`):
    the hidden markers' distances to other blobs. Once the branch is seen again, that level
    let a warm start in another basin stand in: a hexapod leg with two of its four markers
    hidden from all six cameras left a ceiling of 12 px a projection, and in the next
    image its warm start stood in 17° off, reported ``ok``. A trunk keeps it: its legs
    place it (:func:`core.treefit._trunk_by_whole`), and searched on its own third marker it ended
    15-55° off (``tests/core/test_tree.py``).
    """
    out = {}
    for part, points, start, unseen, counted in _compared_parts(q, det, model, rig, params, off):
        kin = part.at(*base_frame(q, model, part))
        image = kernel_image(points, start, params, off, unseen)
        seen, hidden, most = _ceiling_level(q[part.dofs], kin, rig, image, params)
        out[part.name] = (math.nan if most and part.base >= 0
                          else _ceiling(seen, counted, len(part.dofs), hidden, params.empty_view_penalty_px))
    return out


def typical_ceilings(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                     params: FitParams, off: np.ndarray, typical: float) -> dict[str, float]:
    """Per part of ``model.tree`` (by name), the objective per compared marker projection
    below which a re-analysis keeps the part's kept posture ``q`` (D,) without searching it
    again (:func:`core.treefit.refit_tree`): :func:`_ceiling` of the level the sequence's typical
    objective ``typical`` (pixels, ``core.sequence.typical_objective``) gives the part's
    compared projections on ``det``, at ``typical`` shared evenly over the model's markers in
    this image's views with detections.

    Why: under sliding skin markers every image is over the threshold and every part above
    its ε, and the re-analysis searched every part again, to find the part's minimum once
    more. A part no worse than a typical image's, by more than its residual can tell apart,
    leaves a search nothing it could tell from its kept posture, as a warm start under its
    ceiling does (:func:`core.warm_start.warm_start`); a part in another basin costs pixels more than that
    and is searched. Clean footage fits at a typical ~0.01 px a projection, where every
    part that reaches such a level has reached twice its ε already.
    """
    per_projection = typical / max(1, len(model.markers) * det.views_seen)
    return {part.name: _ceiling(per_projection * counted, counted, len(part.dofs))
            for part, _, _, _, counted in _compared_parts(q, det, model, rig, params, off)}


def _compared_parts(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, params: FitParams,
                    off: np.ndarray) -> list[tuple[Part, np.ndarray, np.ndarray, np.ndarray, int]]:
    """Each part of ``model.tree`` with what it is compared with at posture ``q`` (D,): its
    detections (kernel points (n, 3) and view starts (V + 1,); a branch's those within its
    reach), its projections next to another part's marker (``unseen`` (V, m),
    :func:`shared_projections`) and how many projections are compared (:func:`compared_count`)."""
    tree = model.tree
    assert tree is not None
    shared = shared_projections(q, model, rig, tree, params, off)
    reach = reaches(q, det, model, rig, list(tree.branches), off)
    posed = [] if tree.trunk is None else [(tree.trunk, det.kernel_points, det.start)]
    posed += [(b, *subset(det, keep)) for b, keep in zip(tree.branches, reach, strict=True)]
    out = []
    for part, points, start in posed:
        unseen = in_seen_views(shared[part.name], start)
        out.append((part, points, start, unseen, compared_count(unseen, start, len(part.markers))))
    return out


def _ceiling(level: float, counted: int, d: int, hidden: int = 0, penalty: float = 0.0) -> float:
    """A part's ceiling per compared projection (pixels): its objective ``level`` (pixels)
    over ``counted`` projections, ``hidden`` of which look hidden and are not in ``level``,
    plus ``core.undetermined.residual_tolerance`` of ``level`` over the others for another
    minimum anywhere in its ``d`` DOFs, plus ``penalty`` for each hidden one.

    Why the tolerance leaves the hidden projections out: their penalty is not scatter. Read
    as scatter, the penalty of one hidden projection doubled the next warm start's
    allowance, and a leg that had jumped between images stood in for SA in another basin
    (docs/BENCH_SUBJECTS.md, stop 48)."""
    from core.undetermined import residual_tolerance  # it imports this module

    tolerance = residual_tolerance(level, counted - hidden, d, d)
    return (level + tolerance + penalty * hidden) / max(counted, 1)


def judged_in_two_views(unseen: np.ndarray, start: np.ndarray) -> bool:
    """Whether a part's projections not marked ``unseen`` (V, m) lie in two views with
    detections (grouped at ``start``), or in the one view that has any."""
    views = seen_views(start)
    seen = views & ~unseen.all(axis=1) if unseen.size else views
    return int(np.count_nonzero(seen)) >= min(2, int(np.count_nonzero(views)))


def compared_count(unseen: np.ndarray, start: np.ndarray, markers: int) -> int:
    """Marker projections of a part of ``markers`` markers compared with its detections
    grouped at ``start``: markers × views with detections, less the ``unseen`` (V, m) ones."""
    return markers * int(np.count_nonzero(seen_views(start))) - int(np.count_nonzero(unseen))


def missed_by_a_slide(q: np.ndarray, kin, points: np.ndarray, start: np.ndarray, unseen: np.ndarray,
                      rig: Rig, params: FitParams, off: np.ndarray, ceiling: float) -> bool:
    """Whether a part's warm start ``q`` (d,), posed by ``kin`` on the detections ``points``
    grouped at ``start`` (``unseen`` (V, m) left out), missed its ``ceiling`` (pixels per
    compared projection, :func:`warm_ceilings`) as sliding skin markers make it: no
    projection looks hidden (:func:`_lost`) and its level (:func:`_ceiling_level`) is under
    :data:`SLIDE_FACTOR` times the ceiling. Its SA then stops once as low as it
    (:func:`core.treefit._search_stop`).

    Why not every warm start that missed: a leg whose warm start lies in another basin, or
    whose marker is hidden, is pixels off in several views, and its SA, stopped at that
    level, ended in a worse minimum than SA run down to ε (the free fly with markers hidden
    from every camera: median DOF RMSE 1.25 → 4.66°; the 2-camera hexapod with 10 %
    hidden: 76.7 → 68.3 % of images within 5°; docs/BENCH_SUBJECTS.md)."""
    if not math.isfinite(ceiling):
        return False
    image = kernel_image(points, start, params, off, in_seen_views(unseen, start))
    return not _lost(q, kin, rig, image).any() and under_ceiling(q, kin, rig, image, params,
                                                                 SLIDE_FACTOR * ceiling)


def under_ceiling(q: np.ndarray, kin, rig: Rig, image: _kernels.Image, params: FitParams,
                  per_projection: float) -> bool:
    """Whether a part's posture ``q`` (d,), posed by ``kin``, has its level on ``image``
    (:func:`_ceiling_level`) under ``per_projection`` pixels per compared projection (its
    projections in views with detections, less those ``image.unseen`` leaves out)."""
    limit = per_projection * compared_count(image.unseen, image.start, len(kin.marker_joint))
    seen, hidden, _ = _ceiling_level(q, kin, rig, image, params)
    return bool(seen + image.penalty * hidden < limit)
