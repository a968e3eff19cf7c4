"""What a part of a tree is compared with, and how: the lowest layer of the part-by-part fit.

A part (``core.tree.Part``) is posed from the world frame of its base joint
(:func:`world_frames`, :func:`base_frame`) and compared with its detections, grouped by
view, through the kernels' view of them (:func:`kernel_image`, the one construction of a
part's or a whole image's objective), less the projections it leaves out
(:func:`part_objective`); only the views with detections count (:func:`seen_views`).

ε, the SA stop (``AnnealParams.eps``, 1 px), counts per :data:`EPS_PROJECTIONS` marker
projections of a part, 0.25 px each by default (:func:`part_eps`): twice the paper's 1 px
over 4 markers × 2 views, which the detection noise of real markers (0.1-0.2 px a
projection) keeps out of reach of a part seen in many views, so SA would run every part to
its patience limit.

Why a module of its own: ``core.claims``, ``core.ceilings``, ``core.warm_start`` and
``core.treefit`` all pose and score parts this way; here, below them all, it imports none
of them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core import _kernels
from core.error import Detections
from core.model import KinematicModel
from core.rig import Rig
from core.tree import Part

if TYPE_CHECKING:
    from core.fit import FitParams

__all__ = ["EPS_PROJECTIONS", "base_frame", "in_seen_views", "kernel_image", "outside", "part_eps",
           "part_objective", "seen_views", "whole_image", "world_frames"]

EPS_PROJECTIONS = 4  # ε (1 px) per this many marker projections of a part: 0.25 px each


def world_frames(q: np.ndarray, model: KinematicModel) -> tuple[np.ndarray, np.ndarray]:
    """World rotation (J, 3, 3) and origin (J, 3) of every joint, topological order."""
    J = len(model.joints)
    rot, pos = np.empty((J, 3, 3)), np.empty((J, 3))
    _kernels.forward_kinematics(q, model.arrays, rot, pos)
    return rot, pos


def base_frame(q: np.ndarray, model: KinematicModel, part: Part) -> tuple[np.ndarray, np.ndarray]:
    """World rotation (3, 3) and origin (3,) of ``part``'s base joint at posture ``q`` (D,)
    (identity and zero for the root's trunk, which has none)."""
    if part.base < 0:
        return np.eye(3), np.zeros(3)
    rot, pos = world_frames(q, model)
    return rot[part.base], pos[part.base]


def outside(part: Part, n_markers: int) -> np.ndarray:
    """(n_markers,) bool: the model's markers that are not ``part``'s."""
    out = np.ones(n_markers, dtype=bool)
    out[part.markers] = False
    return out


def seen_views(start: np.ndarray) -> np.ndarray:
    """(V,) bool: the views with detections, of detections grouped by view at ``start``
    (V + 1,)."""
    return start[1:] > start[:-1]


def in_seen_views(unseen: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``unseen`` (V, m) bool limited to views with detections (an empty view is charged in
    full whatever it marks)."""
    return np.ascontiguousarray(unseen & seen_views(start)[:, None]) if unseen.size else unseen


def kernel_image(points: np.ndarray, start: np.ndarray, params: FitParams, off: np.ndarray,
                 unseen: np.ndarray = _kernels.NO_UNSEEN) -> _kernels.Image:
    """The kernels' view of detections ``points`` (N, 3) grouped at ``start`` (V + 1,) under
    ``params`` (empty-view penalty, marker fusion) with view offsets ``off`` (V, 2), the
    projections ``unseen`` (V, m) marks left out: the one construction of a part's or a
    whole image's objective here."""
    return _kernels.Image.of(points, start, off, penalty=params.empty_view_penalty_px,
                             fuse_px=params.fusion_px, unseen=unseen)


def whole_image(det: Detections, params: FitParams, off: np.ndarray) -> _kernels.Image:
    """:func:`kernel_image` of a whole image ``det``, no projection left out."""
    return kernel_image(det.kernel_points, det.start, params, off)


def part_objective(q: np.ndarray, kin, points: np.ndarray, start: np.ndarray, unseen: np.ndarray,
                   rig: Rig, params: FitParams, off: np.ndarray) -> float:
    """The objective (pixels) of a part's posture ``q`` (d,) posed by ``kin`` on detections
    ``points`` grouped at ``start``, without the projections ``unseen`` (V, m) marks."""
    unseen = in_seen_views(unseen, start)
    image = kernel_image(points, start, params, off, unseen)
    return float(_kernels.posture_error(q, kin, rig.arrays, image)) - image.penalty * np.count_nonzero(unseen)


def part_eps(part: Part, params: FitParams, views_seen: int) -> float:
    """SA's stop ε for a part (pixels): ``AnnealParams.eps`` per :data:`EPS_PROJECTIONS` of its
    marker projections into the views with detections."""
    return params.anneal.eps * len(part.markers) * views_seen / EPS_PROJECTIONS
