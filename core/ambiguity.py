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
2. :func:`undetermined_alternative` (per image without a distinct minimum): with
   sliding skin markers the true posture is not the minimum, and a short chain seen in
   two views has flat directions (rotation about a segment's long axis, depth). A
   posture more than :data:`UNDETERMINED_DEG` from the fit whose objective stays within
   the image's own :func:`residual_tolerance` is the witness that the image does not
   determine that DOF; it becomes the image's alternative.
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

import numpy as np

from core import _kernels
from core.error import Detections, view_offsets
from core.model import KinematicModel, _topological_order
from core.rig import Rig
from core.treefit import _frames

__all__ = ["MAX_FLIP_REFINES", "PROFILE_STEPS", "UNDETERMINED_DEG", "WITNESS_DOUBLINGS", "Candidate",
           "FlipGeometry", "angle_gaps", "choose_candidates", "confidence_chi2", "flip_alternatives",
           "flip_masks", "residual_tolerance", "undetermined_alternative"]

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
# An image does not determine a DOF when a posture this far from its fit in that DOF (degrees,
# the "more than 10 degrees off the truth") explains it within its tolerance.
UNDETERMINED_DEG = 10.0
CONFIDENCE = 0.99  # postures inside the image's 99 % confidence region are not told apart
_Z_CONFIDENCE = 2.3263  # the standard normal quantile at CONFIDENCE
WITNESS_DOUBLINGS = 3  # a witness is pushed to 2, 4, 8 × UNDETERMINED_DEG while it stays within
PROFILE_STEPS = 10  # LM steps of a witness refined with its DOF held
_SCREEN = 4.0  # DOFs whose linearised rise is above this many tolerances are not tried
_NEAR = 2.0  # a straight step at most this many tolerances beyond the limit is refined


@dataclass(frozen=True)
class Candidate:
    """One posture an image supports: (D,) DOFs, plain Eq. 5 error, minimised objective (pixels)."""

    dofs: np.ndarray
    error: float
    objective: float


@dataclass(frozen=True)
class FlipGeometry:
    """What the depth flips of a model seen by a rig need, computed once per model and rig.

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
    subtree_markers = subtree_joints[:, marker_joint].reshape(len(flip_joints), M)
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
    n = _kernels.flip_alternatives(
        fit.dofs, fit.objective, float(tolerance_px), model.lower, model.upper, model.arrays,
        rig.arrays, off, detections.kernel_points, detections.start, float(empty_view_penalty_px),
        float(fusion_px), float(huber_px), geo.flip_joints, geo.subtree_joints, geo.subtree_markers,
        geo.depth, geo.perspective, geo.masks, MAX_FLIP_REFINES, out_q, out_objective,
    )
    return [
        Candidate(out_q[k].copy(), _plain_error(out_q[k], detections, model, rig, off,
                                                empty_view_penalty_px), float(out_objective[k]))
        for k in range(n)
    ]


def _plain_error(q, detections, model, rig, offsets, penalty) -> float:
    return float(_kernels.posture_error(q, model.arrays, rig.arrays, offsets, detections.kernel_points,
                                        detections.start, float(penalty), 0.0, _kernels.NO_UNSEEN))


def confidence_chi2(k: int) -> float:
    """χ² of ``k`` degrees of freedom at :data:`CONFIDENCE` (Wilson–Hilferty: within 1 % of
    the exact quantile for every k).

    >>> round(confidence_chi2(1), 2), round(confidence_chi2(6), 2)
    (6.59, 16.84)
    """
    c = 2.0 / (9.0 * k)
    return k * (1.0 - c + _Z_CONFIDENCE * math.sqrt(c)) ** 3


def residual_tolerance(error_px: float, compared: int, n_dofs: int, tested_dofs: int) -> float:
    """Pixels of Eq. 5 within which an image cannot tell postures apart, from its own residual.

    ``error_px`` is the fit's plain Eq. 5 error over ``compared`` marker projections, for a
    model of ``n_dofs`` DOFs; ``tested_dofs`` is how many DOFs the postures compared may
    differ in: 1 for one DOF's confidence interval, ``n_dofs`` for another minimum anywhere.
    A fit's mean distance ē per projection estimates the per-coordinate scatter σ of the
    markers about the model (slid skin, noise): σ² = ē² · 2/π (a 2-D distance of
    per-coordinate σ has mean σ√(π/2)), times 2n / (2n − D) because the fit absorbs D of
    the 2n coordinates. A posture at the edge of the confidence region raises Σ‖r‖² by
    χ²(tested) · σ² (:func:`confidence_chi2`), so Eq. 5 (Σ‖r‖, distances near ē) by about
    χ² · σ² / (2ē) = χ² · ē · 2n / ((2n − D) π). An image fitted at 1 px a projection
    cannot tell apart postures a few pixels apart; one fitted at 0.05 px can. NaN or no
    projections: 0.

    >>> round(residual_tolerance(8.0, 8, 6, 1), 2), round(residual_tolerance(8.0, 8, 6, 6), 2)
    (3.35, 8.58)
    """
    if compared <= 0 or not math.isfinite(error_px):
        return 0.0
    coords = 2 * compared
    return (confidence_chi2(tested_dofs) * (error_px / compared) * coords
            / (max(coords - n_dofs, 1) * math.pi))


def undetermined_alternative(
    fit: Candidate,
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    tolerance_px: float,
    fusion_px: float,
    empty_view_penalty_px: float,
    huber_px: float,
    offsets: np.ndarray | None = None,
) -> Candidate | None:
    """A posture at least :data:`UNDETERMINED_DEG` from ``fit`` in some rotational DOF whose
    objective is within ``tolerance_px`` of the fit's, or None: the witness that the image
    does not determine that DOF (step 2 of the module).

    Each rotational DOF d is moved along its profile, the linearised best way to move d
    with every other DOF following (column d of (JᵀJ)⁻¹, J the Jacobian of the
    projections), by ±:data:`UNDETERMINED_DEG`, then 2, 4, 8 times as far while the
    objective (as the fit's: fusion, a lost marker per view) stays within the tolerance;
    a step that leaves it by less than :data:`_NEAR` tolerances is refined with d held
    (towards the profile's minimum, nonlinear).
    DOFs whose linearised rise at the first step is above :data:`_SCREEN` tolerances are
    not tried (most DOFs of a clean image: the search costs a Jacobian and a few errors).
    Of the postures within the tolerance, the one farthest from the fit.
    """
    q = fit.dofs
    rot = model.rotational
    compared = int(np.count_nonzero(detections.counts)) * len(model.markers)
    if not rot.any() or not math.isfinite(fit.error) or tolerance_px <= 0 or compared == 0:
        return None
    off = view_offsets(offsets, rig)
    kin, views, points, start = model.arrays, rig.arrays, detections.kernel_points, detections.start
    penalty = float(empty_view_penalty_px)

    def objective(p: np.ndarray) -> float:
        return float(_kernels.posture_error(p, kin, views, off, points, start, penalty,
                                            float(fusion_px), _kernels.NO_UNSEEN, penalty))

    def pinned(p: np.ndarray, d: int) -> np.ndarray:
        """``p`` refined with DOF d held: the whole model, or for a tree (``core.tree``) d's
        part alone, the rest where ``p`` puts it (a leg's DOFs, not all 42)."""
        dofs, part_kin = np.arange(len(p)), kin
        if model.tree is not None:
            part = next(x for x in model.tree.parts if d in x.dofs)
            rotation, origin = _frames(p, model)
            dofs, part_kin = part.dofs, part.at(rotation[part.base], origin[part.base])
        lower, upper = model.lower[dofs].copy(), model.upper[dofs].copy()
        lower[dofs == d] = upper[dofs == d] = p[d]
        out = p.copy()
        out[dofs] = _kernels.refine(p[dofs].copy(), lower, upper, part_kin, views, off, points,
                                    start, penalty, float(fusion_px), _kernels.NO_UNSEEN,
                                    float(huber_px), PROFILE_STEPS, 1e-5, _kernels.NO_TARGETS)
        return out

    profiles, moves = _profiles(q, model, rig, detections)
    mean = max(fit.error / compared, 1e-12)
    # Linearised rise of Eq. 5 at the first step: a projection moved by m from a residual
    # of about ē rises by ~m²/(2ē) while m << ē, by ~m when m >> ē.
    step_moves = UNDETERMINED_DEG * moves
    rise = np.minimum(step_moves, step_moves**2 / (2 * mean)).sum(axis=1)
    screened = rise <= _SCREEN * tolerance_px
    limit = objective(q) + tolerance_px
    best, best_gap = None, UNDETERMINED_DEG
    for d in np.flatnonzero(rot & screened):
        for sign in (1.0, -1.0):
            for k in range(WITNESS_DOUBLINGS + 1):
                step = sign * UNDETERMINED_DEG * 2**k
                p = np.clip(q + step * profiles[d], model.lower, model.upper)
                if limit < objective(p) <= limit + _NEAR * tolerance_px:
                    p = pinned(p, int(d))
                gap = float(angle_gaps(p, q)[rot].max())
                if objective(p) > limit or gap < abs(step) * (1 - 1e-9):  # worse, or at a bound
                    break
                if gap >= best_gap:
                    best, best_gap = p, gap
    if best is None:
        return None
    return Candidate(best, _plain_error(best, detections, model, rig, off, penalty), objective(best))


def angle_gaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Absolute differences of two postures, degrees the shorter way round (meaningful for
    rotational DOFs only)."""
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def _profiles(q: np.ndarray, model: KinematicModel, rig: Rig,
              detections: Detections) -> tuple[np.ndarray, np.ndarray]:
    """Profile directions (D, D), row d the change of every DOF per unit change of DOF d,
    and (D, P) how far each of the P compared marker projections moves along each, pixels
    per unit, from the Jacobian J of the projections in the views with detections (forward
    differences; linearised least squares: column d of (JᵀJ)⁻¹)."""
    D = len(q)
    h = 1e-3
    postures = np.repeat(q[None], D + 1, axis=0)
    postures[1:] += np.eye(D) * h
    proj = rig.project(model.marker_positions(postures))  # (D + 1, V, M, 2)
    seen = np.asarray(detections.counts) > 0
    J = ((proj[1:] - proj[:1])[:, seen] / h).reshape(D, -1).T  # (2P, D)
    A = J.T @ J
    A += np.eye(D) * (1e-9 * max(float(np.trace(A)) / D, 1e-12))  # a DOF no marker moves
    C = np.linalg.inv(A)
    profiles = (C / np.diag(C)[None, :]).T
    moves = np.linalg.norm((J @ profiles.T).T.reshape(D, -1, 2), axis=2)
    return profiles, moves


def choose_candidates(candidates: Sequence[Sequence[Candidate]]) -> list[int]:
    """Index of the chosen candidate of every image (step 2), by one Viterbi pass.

    ``candidates[t]``: image t's candidates, its fit first; an empty list (no
    detections) breaks the sequence. Cost of a choice: how much worse than the
    image's best it scores, in units of the sequence's typical objective, plus
    half the squared move from the previous image's choice in units of the
    sequence's typical per-image movement of each DOF (capped: a sequence may
    jump). Images with a single candidate keep it.
    """
    n = len(candidates)
    choice = [0] * n
    if all(len(c) <= 1 for c in candidates):
        return choice
    error_scale, step = _scales(candidates)
    t = 0
    while t < n:
        end = t
        while end < n and candidates[end]:
            end += 1
        choice[t:end] = _viterbi(candidates[t:end], error_scale, step)
        t = end + 1
    return choice


def _scales(candidates: Sequence[Sequence[Candidate]]) -> tuple[float, np.ndarray]:
    """Typical objective of a fit, and typical per-image move of each DOF (closest pairs)."""
    objectives = [c[0].objective for c in candidates if c]
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
