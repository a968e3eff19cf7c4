"""A start for one branch from triangulated candidates: inverse kinematics onto them.

``core.triangulate`` proposes 3D points where markers may be, without labels. A branch
(``core.tree.Part``) whose base frame is known (the trunk is fitted) is posed onto them by a
beam search over assignments, proximal markers first: each of the branch's markers, in order
of its distance from the base at the start posture, is given in turn each free candidate
within the branch's reach (or none, at a cost), the branch's DOFs are solved by inverse
kinematics onto the markers assigned so far (``core._kernels.refine`` in target mode: bounded
Levenberg-Marquardt), and the :data:`BEAM` assignments of least residual go on to the next
marker. A proximal marker moves with few DOFs, so its candidates are few and its residual
tells them apart; each later marker is then sought from a posture that already places it
nearly right. Nearest-candidate assignment from one posture (ICP) lands in the wrong basin
for most legs: a distal marker's nearest candidate is usually another marker's.

The result is a start for the search, never its result: it is only as good as the
candidates, and its Eq. 5 error says whether it explains the images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core import _kernels
from core.model import KinematicArrays, KinematicModel
from core.rig import Rig
from core.tree import REACH_MARGIN, Part

__all__ = ["BranchStart", "branch_start"]

BEAM = 4  # partial assignments kept after each marker
IK_STEPS = 30
MIN_ASSIGNED = 2  # fewer assigned markers cannot fix a branch's posture
TIE_PX = 0.01  # final postures within this Eq. 5 error are told apart by their residual
SKIP_FRACTION = 0.05  # leaving a marker unassigned costs (this × the branch's reach)², model units²


@dataclass(frozen=True)
class BranchStart:
    """A branch posture proposed from candidates.

    dofs : ndarray of shape (d,), float64, the branch's DOFs (``Part.dofs`` order; degrees,
        model units), inside their ranges.
    error : Eq. 5 of the branch's markers at ``dofs`` against the detections given, pixels.
    assigned : how many of the branch's markers were posed onto a candidate.
    """

    dofs: np.ndarray
    error: float
    assigned: int


@dataclass(frozen=True)
class _Beam:
    """A partial assignment: ``targets`` (M,) candidate index per marker, -1 unassigned or
    not yet reached; posture ``q`` (d,) solved onto it; ``residual``: squared distances of the
    assigned markers to their targets, and ``skips``: the charge of the markers left out
    (model units²)."""

    targets: np.ndarray
    q: np.ndarray
    residual: float
    skips: float

    @property
    def cost(self) -> float:
        return self.residual + self.skips


def branch_start(candidates: np.ndarray, *, part: Part, rotation: np.ndarray, origin: np.ndarray,
                 q0: np.ndarray, model: KinematicModel, rig: Rig, points: np.ndarray,
                 start: np.ndarray, offsets: np.ndarray, empty_view_penalty_px: float,
                 ) -> BranchStart | None:
    """Pose ``part`` onto ``candidates`` from ``q0``: of the beam search's final assignments,
    the one whose posture has least Eq. 5 error (within :data:`TIE_PX`, least residual).

    Parameters
    ----------
    candidates : ndarray of shape (K, 3), float64, model units, world frame
        (``core.triangulate.Candidates.points``); those beyond the branch's reach
        (``REACH_MARGIN`` × ``part.reach`` from ``origin``) are ignored.
    part : a branch of ``core.tree.decompose(model)``.
    rotation, origin : ndarray of shape (3, 3) and (3,): the world frame of the part's base
        joint (model units), from the fitted trunk.
    q0 : ndarray of shape (d,), float64: the part's DOFs to start from (the histogram mean).
    points, start : the detections as the kernels take them (``Detections.kernel_points``
        (N, 3) and view starts (V + 1,)), for the Eq. 5 error.
    offsets : ndarray of shape (V, 2), float64, pixels added to every projection of a view.

    Returns
    -------
    BranchStart, or None when fewer than :data:`MIN_ASSIGNED` candidates lie within reach.
    Cost: about ``M × BEAM × K_reach`` inverse kinematics of the branch (M markers,
    ``K_reach`` candidates within reach).
    """
    near = np.linalg.norm(candidates - origin, axis=1) <= REACH_MARGIN * part.reach
    targets = np.ascontiguousarray(candidates[near])
    if len(targets) < MIN_ASSIGNED:
        return None
    kin = part.at(rotation, origin)
    lower, upper = model.lower[part.dofs], model.upper[part.dofs]
    q = np.clip(q0, lower, upper)
    order = np.argsort(np.linalg.norm(_markers(q, kin) - origin, axis=1), kind="stable")
    skip = (SKIP_FRACTION * part.reach) ** 2
    beams = [_Beam(np.full(len(order), -1, dtype=np.int64), q, 0.0, 0.0)]
    for m in order:
        grown = []
        for beam in beams:
            grown.append(_Beam(beam.targets, beam.q, beam.residual, beam.skips + skip))
            for k in np.setdiff1d(np.arange(len(targets)), beam.targets):
                assigned = beam.targets.copy()
                assigned[m] = k
                grown.append(_solve(assigned, beam.q, kin, targets, lower, upper, rig, points,
                                    start, offsets, beam.skips))
        beams = sorted(grown, key=lambda b: b.cost)[:BEAM]
    found = []
    for beam in beams:
        n = int(np.count_nonzero(beam.targets >= 0))
        if n >= MIN_ASSIGNED:
            error = float(_kernels.posture_error(beam.q, kin, rig.arrays, offsets, points, start,
                                                 float(empty_view_penalty_px), 0.0, _kernels.NO_UNSEEN))
            found.append((error, beam.cost, BranchStart(beam.q, error, n)))
    if not found:
        return None
    least = min(e for e, _, _ in found)
    return min((f for f in found if f[0] <= least + TIE_PX), key=lambda f: f[1])[2]


def _markers(q: np.ndarray, kin: KinematicArrays) -> np.ndarray:
    """(M, 3) world marker positions of the part posed at ``q``."""
    return _kernels.marker_positions_many(q[None], kin)[0]


def _solve(assigned: np.ndarray, q: np.ndarray, kin: KinematicArrays, targets: np.ndarray,
           lower: np.ndarray, upper: np.ndarray, rig: Rig, points: np.ndarray, start: np.ndarray,
           offsets: np.ndarray, skips: float) -> _Beam:
    """Inverse kinematics from ``q`` of the markers ``assigned`` (M,) onto their targets."""
    posed = assigned >= 0
    sub = kin._replace(marker_joint=kin.marker_joint[posed],
                       marker_pos=np.ascontiguousarray(kin.marker_pos[posed]))
    solved = _kernels.refine(q, lower, upper, sub, rig.arrays, offsets, points, start, 0.0, 0.0,
                             _kernels.NO_UNSEEN, np.inf, IK_STEPS, 1e-5,
                             np.ascontiguousarray(targets[assigned[posed]]))
    d = _markers(solved, kin)[posed] - targets[assigned[posed]]
    return _Beam(assigned, solved, float(np.sum(d * d)), skips)
