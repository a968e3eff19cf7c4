"""Ambiguous postures: finding the ones that image alike, and choosing among them.

A view does not see depth. With one view, or where the views happen to agree,
a leg and its reflection through a plane normal to a viewing direction image
identically (the paper's Fig. 6 arrows and Fig. 9): for known segment lengths
each segment can flip forwards or backwards (Sminchisescu & Triggs, "Kinematic
jump processes for monocular 3D human tracking", CVPR 2003). SA lands in one of
these minima at random, and stops there once its error is below ε.

Two steps deal with it, neither of which gives up fitting every image alone:

1. :func:`flip_alternatives` (per image, after its fit): every view's depth
   flips of every subtree below a joint with DOFs are tried; those the model can
   reach within its ranges and that score within a tolerance of the fit are the
   image's alternatives, and the best-scoring of all becomes the fit.
2. ``core.undetermined`` (per image without a distinct minimum): a posture far from the
   fit in a DOF the image does not determine, within the image's own tolerance.
3. :func:`choose_candidates` (per sequence, after re-analysis): among each image's
   candidates, one per image is chosen to minimise, over the sequence, how much
   worse than the image's best candidate it scores plus how far the posture
   moves from one image to the next (a Viterbi pass). This is the paper's
   proposal (§4) to "exploit a plausible motion continuity property" without
   relying on the angles of previous frames: it only arbitrates between
   postures each image supports equally.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import NamedTuple

import numpy as np

from core import _kernels
from core.error import Detections, view_offsets
from core.model import KinematicModel, _topological_order
from core.rig import Rig

__all__ = ["DISTINCT_DEG", "MAX_FLIP_REFINES", "Candidate", "FlipGeometry", "angle_gaps",
           "choose_candidates", "distinct", "flip_alternatives", "flip_masks", "plain_error"]

DISTINCT_DEG = 5.0  # a posture differs from another (another minimum) by more than this in some angle
MAX_ALTERNATIVES = 8
# Flips refined per image at most. A flip that passes the screen (it images within the
# tolerance) is refined twice (inverse kinematics, then 50 LM steps), each step costing
# D·evaluation + V·M·D²: with one flip per joint, a model of many joints whose leaf flips all
# pass made the search grow with the fourth power of its size. The locust leg tries 14
# (3 flip joints: 7 subsets, 2 views), and keeps every one.
MAX_FLIP_REFINES = 16
_MAX_FULL_SUBSETS = 4  # flip joints up to which every subset is tried; beyond, one at a time
_MIN_STEP = 0.5  # degrees (model units) per image: the smallest movement scale assumed
_MIN_ERROR_SCALE_PX = 0.05


@dataclass(frozen=True)
class Candidate:
    """One posture an image supports: (D,) DOFs, plain Eq. 5 error, minimised objective
    (pixels); ``minimum`` False for a witness that the image does not determine a DOF
    (``core.undetermined``): a point on a flat valley at a set step from the fit, not a
    minimum, which the choice by continuity does not take."""

    dofs: np.ndarray
    error: float
    objective: float
    minimum: bool = True


class FlipGeometry(NamedTuple):
    """What the depth flips of a model seen by a rig need, computed once per model and rig;
    the kernel ``core._kernels.flip_alternatives`` takes it as it is (a named tuple).

    flip_joints : (F,) topological indices of the joints with rotational DOFs.
    subtree_joints, subtree_markers : (F, J), (F, M) bool, what lies at or below each.
    depth : (V, 3) unit viewing direction, or the camera centre where ``perspective`` (V,).
    masks : subsets of flip joints to try (bit f: flip joint f).
    """

    flip_joints: np.ndarray
    subtree_joints: np.ndarray
    subtree_markers: np.ndarray
    depth: np.ndarray
    perspective: np.ndarray
    masks: np.ndarray

    @classmethod
    def of(cls, model: KinematicModel, rig: Rig) -> FlipGeometry:
        """The geometry of ``model`` seen through ``rig`` (build once per chunk, not per image)."""
        return _build_geometry(model, rig)


def _build_geometry(model: KinematicModel, rig: Rig) -> FlipGeometry:
    order = _topological_order(model.joints)
    topo = {model.joints[i].name: k for k, i in enumerate(order)}
    parent = model.arrays.parent
    J, M = len(order), len(model.markers)
    flip = [topo[d.joint] for d in model.dofs if d.rotational]
    flip_joints = np.array(sorted(set(flip)), dtype=np.int64)
    below = np.zeros((J, J), dtype=bool)  # below[j, k]: k is j or a descendant of j
    for k in range(J):  # parents come first in topological order
        below[k, k] = True
        if parent[k] >= 0:
            below[:, k] |= below[:, parent[k]]
    marker_joint = model.arrays.marker_joint
    subtree_joints = below[flip_joints]
    # C order whatever the shapes (fancy indexing may give F order): one kernel signature
    subtree_markers = np.ascontiguousarray(subtree_joints[:, marker_joint].reshape(len(flip_joints), M))
    depth, perspective = _view_depths(rig)
    return FlipGeometry(flip_joints, subtree_joints, subtree_markers, depth, perspective,
                        flip_masks(len(flip_joints)))


def flip_masks(n_flip_joints: int) -> np.ndarray:
    """The subsets of flip joints tried in each view, (K,) int64 bit masks (bit f: flip joint f):
    every non-empty subset of up to four flip joints, else each joint alone.

    >>> flip_masks(2).tolist(), flip_masks(5).tolist()
    ([1, 2, 3], [1, 2, 4, 8, 16])
    """
    F = n_flip_joints
    return (np.arange(1, 1 << F, dtype=np.int64) if F <= _MAX_FULL_SUBSETS
            else (1 << np.arange(F, dtype=np.int64)))


def _view_depths(rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """Per view: the unit direction it cannot see (affine), or its camera centre."""
    a = rig.arrays
    depth = np.zeros((len(rig.views), 3))
    perspective = np.zeros(len(rig.views), dtype=bool)
    for v in range(len(rig.views)):
        P = a.P[v]
        if a.kind[v] == _kernels.AFFINE:
            n = np.cross(P[0, :3], P[1, :3])
            depth[v] = n / np.linalg.norm(n)
        elif a.kind[v] == _kernels.PINHOLE:  # P holds [R | t]
            depth[v] = -P[:, :3].T @ P[:, 3]
            perspective[v] = True
        else:  # DLT: the centre is P's null vector
            centre = np.linalg.svd(P)[2][-1]
            depth[v] = centre[:3] / centre[3] if abs(centre[3]) > 1e-12 else centre[:3] * 1e9
            perspective[v] = True
    return depth, perspective


def flip_alternatives(
    fit: Candidate,
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    geometry: FlipGeometry,
    tolerance_px: float,
    fusion_px: float,
    empty_view_penalty_px: float,
    huber_px: float,
    offsets: np.ndarray | None = None,
) -> list[Candidate]:
    """Postures scoring within ``tolerance_px`` of ``fit`` reached by depth flips (step 1).

    Returns up to :data:`MAX_ALTERNATIVES` candidates, distinct from ``fit`` and
    from each other (some DOF more than 1 degree or model unit apart); at most
    :data:`MAX_FLIP_REFINES` flips that pass the screen are refined.
    """
    geo = geometry
    if len(geo.flip_joints) == 0 or not math.isfinite(fit.objective):
        return []
    out_q = np.empty((MAX_ALTERNATIVES, len(model.dofs)))
    out_objective = np.empty(MAX_ALTERNATIVES)
    off = view_offsets(offsets, rig)
    image = _kernels.Image.of(detections.kernel_points, detections.start, off,
                              penalty=empty_view_penalty_px, fuse_px=fusion_px)
    n = _kernels.flip_alternatives(
        fit.dofs, float(fit.objective), float(tolerance_px), _kernels.Bounds(model.lower, model.upper),
        model.arrays, rig.arrays, image, float(huber_px), geo, MAX_FLIP_REFINES, out_q, out_objective,
    )
    return [
        Candidate(out_q[k].copy(), plain_error(out_q[k], detections, model, rig, off,
                                                empty_view_penalty_px), float(out_objective[k]))
        for k in range(n)
    ]


def plain_error(q: np.ndarray, detections: Detections, model: KinematicModel, rig: Rig,
                offsets: np.ndarray, penalty: float) -> float:
    """Plain Eq. 5 (pixels, no fusion) of posture ``q`` (D,) on ``detections``, views shifted by
    ``offsets`` (V, 2); a view without detections costs ``penalty`` px per marker."""
    image = _kernels.Image.of(detections.kernel_points, detections.start, offsets, penalty=penalty,
                              fuse_px=0.0)
    return float(_kernels.plain_error(q, model.arrays, rig.arrays, image))


def angle_gaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Absolute differences of two postures, degrees the shorter way round (meaningful for
    rotational DOFs only)."""
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def distinct(a: np.ndarray, b: np.ndarray, rotational: np.ndarray) -> bool:
    """Whether postures ``a`` and ``b`` (same shape) differ by more than :data:`DISTINCT_DEG`
    in some angle (``rotational``, bool, marks the angles)."""
    return bool(angle_gaps(a, b)[rotational].max(initial=0.0) > DISTINCT_DEG)


def choose_candidates(candidates: Sequence[Sequence[Candidate]],
                      beyond_px: Sequence[float] | None = None) -> list[int]:
    """Index of the chosen candidate of every image (step 2), by one Viterbi pass.

    ``candidates[t]``: image t's candidates, its fit first; an empty list (no
    detections) breaks the sequence. Cost of a choice: how much worse than the
    image's best it scores, in units of the sequence's typical objective, plus
    half the squared move from the previous image's choice in units of the
    sequence's typical per-image movement of each DOF (capped: a sequence may
    jump). Images with a single candidate keep it.

    ``beyond_px[t]`` (px, optional): what image t's fit is charged for projections beyond
    their views' edges, left out of the typical objective. A limb out of the frame costs
    every image the same penalty, which tells no posture from another: read as misfit it
    made the typical objective five times the images' residual, and a candidate 10 px
    above the right one cost the choice less than the right one's move
    (docs/BENCH_SUBJECTS.md, stop 53).
    """
    n = len(candidates)
    choice = [0] * n
    if all(len(c) <= 1 for c in candidates):
        return choice
    error_scale, step = _scales(candidates, [0.0] * n if beyond_px is None else beyond_px)
    t = 0
    while t < n:
        end = t
        while end < n and candidates[end]:
            end += 1
        if end > t:  # not an image without detections (the first, or one after another)
            choice[t:end] = _viterbi(candidates[t:end], error_scale, step)
        t = end + 1
    return choice


def _scales(candidates: Sequence[Sequence[Candidate]],
            beyond_px: Sequence[float]) -> tuple[float, np.ndarray]:
    """Typical objective of a fit without its charge ``beyond_px`` (one per image), and
    typical per-image move of each DOF (closest pairs)."""
    objectives = [c[0].objective - b for c, b in zip(candidates, beyond_px, strict=True) if c]
    error_scale = max(_MIN_ERROR_SCALE_PX, float(np.median(objectives)))
    moves = []
    for prev, cur in pairwise(candidates):
        if prev and cur:
            diffs = np.array([[np.abs(a.dofs - b.dofs) for b in cur] for a in prev])
            flat = diffs.reshape(-1, diffs.shape[-1])
            moves.append(flat[np.argmin(flat.sum(axis=1))])
    dim = len(next(c for c in candidates if c)[0].dofs)
    step = (1.4826 * np.median(np.array(moves), axis=0) if moves else np.zeros(dim))
    return error_scale, np.maximum(step, _MIN_STEP)


def _viterbi(run: Sequence[Sequence[Candidate]], error_scale: float, step: np.ndarray) -> list[int]:
    unary = [np.array([(c.objective - min(x.objective for x in cands)) / error_scale for c in cands])
             for cands in run]
    cost, back = unary[0], []
    for prev, cur, u in zip(run[:-1], run[1:], unary[1:], strict=True):
        a = np.array([c.dofs for c in prev])
        b = np.array([c.dofs for c in cur])
        move = np.log1p(((b[None, :, :] - a[:, None, :]) / step) ** 2).sum(axis=2)
        total = cost[:, None] + move
        back.append(np.argmin(total, axis=0))
        cost = total.min(axis=0) + u
    path = [int(np.argmin(cost))]
    for pointers in reversed(back):
        path.append(int(pointers[path[-1]]))
    return path[::-1]
