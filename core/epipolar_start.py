"""A start for one branch from triangulated candidates: inverse kinematics onto them.

``core.triangulate`` proposes 3D points where markers may be, without labels. A branch
(``core.tree.Part``) whose base frame is known (the parts above it are fitted) is posed onto
them by a beam search over assignments, proximal markers first: each of the branch's markers, in order
of its distance from the base at the start posture, is given in turn each free candidate
that the branch's geometry allows (or none, at a cost), the branch's DOFs are solved by
inverse kinematics onto the markers assigned so far (``core._kernels.refine`` in target mode: bounded
Levenberg-Marquardt), and the :data:`BEAM` assignments of least residual go on to the next
marker. A proximal marker moves with few DOFs, so its candidates are few and its residual
tells them apart; each later marker is then sought from a posture that already places it
nearly right. Nearest-candidate assignment from one posture (ICP) lands in the wrong basin
for most legs: a distal marker's nearest candidate is usually another marker's.

The geometry prunes before any inverse kinematics: over :data:`SAMPLES` postures spread
through the DOF ranges, every marker's distance from the base origin and from every other
marker of the branch spans an interval (a point on a rigid segment: a single length); a
candidate is tried for a marker only if its distances to the base and to the candidates
already assigned fall in those intervals, widened by :data:`SLACK_FRACTION` of the reach,
and only the :data:`TRIES` best supported of them, nearest the marker's place at the beam's
posture first. The search itself is compiled (``core._epipolar_kernels.beam_search``); this
module prepares its arrays and picks among the assignments it ends with.

The root's trunk (a part without a base, free to translate: :func:`trunk_start`) has no
base to measure distances from and candidates anywhere in the arena, so it is posed from
three of its markers at once: every three candidates whose distances from each other the
trunk's geometry allows (sampled as above, widened by :data:`TRUNK_SLACK_FRACTION` of the
markers' spread), solved by inverse kinematics onto them.

The result is a start for the search, never its result: it is only as good as the
candidates, and its Eq. 5 error says whether it explains the images.
"""

from __future__ import annotations

from dataclasses import dataclass
from weakref import WeakKeyDictionary

import numpy as np

from core import _epipolar_kernels, _kernels
from core.model import KinematicArrays, KinematicModel
from core.rig import Rig
from core.tree import REACH_MARGIN, Part
from core.triangulate import Candidates

__all__ = ["BranchStart", "branch_start", "trunk_start"]

BEAM = 8  # partial assignments kept after each marker
IK_STEPS = 10
MIN_ASSIGNED = 2  # fewer assigned markers cannot fix a branch's posture
TIE_PX = 0.01  # final postures within this Eq. 5 error are told apart by their residual
SKIP_FRACTION = 0.05  # leaving a marker unassigned costs (this × the branch's reach)², model units²
SAMPLES = 512  # postures whose marker distances bound the candidates' (low-discrepancy)
SLACK_FRACTION = 0.02  # of the branch's reach: widens the sampled distance intervals
TRIES = 6  # candidates tried per marker and beam
TRUNK_SLACK_FRACTION = 0.05  # of the trunk markers' spread: widens their distance intervals
TRUNK_IK_STEPS = 20  # a free trunk may turn far from its start
TRUNK_TRIANGLES = 4  # the trunk's marker triples tried, widest first
MAX_TRIPLES = 1000  # candidate triples solved per trunk start, best supported first


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


def branch_start(candidates: Candidates, *, part: Part, rotation: np.ndarray, origin: np.ndarray,
                 q0: np.ndarray, model: KinematicModel, rig: Rig, points: np.ndarray,
                 start: np.ndarray, offsets: np.ndarray, empty_view_penalty_px: float,
                 ) -> BranchStart | None:
    """Pose ``part`` onto ``candidates`` from ``q0``: of the beam search's final assignments,
    the one whose posture has least Eq. 5 error (within :data:`TIE_PX`, least residual).

    Parameters
    ----------
    candidates : the image's ``core.triangulate.Candidates``; those beyond the branch's reach
        (``REACH_MARGIN`` × ``part.reach`` from ``origin``) are ignored. Assigning one that
        fewer views support than the best supported costs up to a skip (:func:`_doubt`).
    part : a branch of ``core.tree.decompose(model)``.
    rotation, origin : ndarray of shape (3, 3) and (3,): the world frame of the part's base
        joint (model units), from the parts fitted before it.
    q0 : ndarray of shape (d,), float64: the part's DOFs to start from (the histogram mean).
    points, start : the detections as the kernels take them (``Detections.kernel_points``
        (N, 3) and view starts (V + 1,)), for the Eq. 5 error.
    offsets : ndarray of shape (V, 2), float64, pixels added to every projection of a view.

    Returns
    -------
    BranchStart, or None when fewer than :data:`MIN_ASSIGNED` candidates lie within reach.
    Cost: at most ``M × BEAM × TRIES`` inverse kinematics of the branch (M markers), each
    :data:`IK_STEPS` Levenberg-Marquardt steps at most.
    """
    near = np.linalg.norm(candidates.points - origin, axis=1) <= REACH_MARGIN * part.reach
    targets = np.ascontiguousarray(candidates.points[near])
    if len(targets) < MIN_ASSIGNED:
        return None
    kin = part.at(rotation, origin)
    lower, upper = model.lower[part.dofs], model.upper[part.dofs]
    q = np.clip(q0, lower, upper)
    order = np.argsort(np.linalg.norm(_markers(q, kin) - origin, axis=1), kind="stable")
    skip = (SKIP_FRACTION * part.reach) ** 2
    low, high = _part_bounds(part, lower, upper)
    refine_image = _kernels.Image.of(points, start, offsets, penalty=0.0, fuse_px=0.0)  # not read
    assigned, postures, costs = _epipolar_kernels.beam_search(
        order, q, kin, _kernels.Bounds(lower, upper), rig.arrays, refine_image, targets,
        np.linalg.norm(targets - origin, axis=1), np.linalg.norm(targets[:, None] - targets[None], axis=2),
        skip * _doubt(candidates.n_views[near]), low, high, skip, BEAM, TRIES, IK_STEPS)
    image = _kernels.Image.of(points, start, offsets, penalty=empty_view_penalty_px, fuse_px=0.0)
    found = []
    for targeted, posture, cost in zip(assigned, postures, costs, strict=True):
        n = int(np.count_nonzero(targeted >= 0))
        if n >= MIN_ASSIGNED:
            error = float(_kernels.posture_error(posture, kin, rig.arrays, image))
            found.append((error, cost, BranchStart(posture, error, n)))
    if not found:
        return None
    least = min(e for e, _, _ in found)
    return min((f for f in found if f[0] <= least + TIE_PX), key=lambda f: f[1])[2]


def trunk_start(candidates: Candidates, *, part: Part, q0: np.ndarray, model: KinematicModel, rig: Rig,
                points: np.ndarray, start: np.ndarray, offsets: np.ndarray, empty_view_penalty_px: float,
                ) -> BranchStart | None:
    """Pose the root's trunk ``part`` (``part.base`` -1) onto ``candidates``: the posture, of
    least Eq. 5 error over its markers, that inverse kinematics (``_kernels.refine`` in
    target mode, :data:`TRUNK_IK_STEPS` steps from ``q0``) reaches on three candidates placed
    as three of its markers.

    The markers' triples are tried widest first (triangle area at ``q0``, at most
    :data:`TRUNK_TRIANGLES`); a triple of candidates is tried for one where each two lie as
    far apart as the two markers may (:func:`_distance_bounds` over the DOF ranges, widened
    by :data:`TRUNK_SLACK_FRACTION` of the markers' spread), at most :data:`MAX_TRIPLES`
    per triple of markers, those more views support first. A rigid trunk's distances are
    single lengths, so few triples pass.

    Parameters and the result as :func:`branch_start` (``q0`` the trunk's DOFs to start from;
    no base frame: the trunk's kinematic arrays are in the world frame). None for a trunk
    of fewer than three markers, or when no three candidates fit.
    Cost: at most :data:`TRUNK_TRIANGLES` × :data:`MAX_TRIPLES` inverse kinematics of the trunk.
    """
    kin, markers = part.kin, len(part.markers)
    if markers < 3 or len(candidates) < 3:
        return None
    lower, upper = model.lower[part.dofs], model.upper[part.dofs]
    q = np.clip(q0, lower, upper)
    places = _markers(q, kin)
    spread = float(np.linalg.norm(places[:, None] - places[None], axis=2).max())
    low, high = _distance_bounds(kin, lower, upper, TRUNK_SLACK_FRACTION * spread)
    apart = np.linalg.norm(candidates.points[:, None] - candidates.points[None], axis=2)
    support = candidates.n_views
    bounds = _kernels.Bounds(lower, upper)
    image = _kernels.Image.of(points, start, offsets, penalty=empty_view_penalty_px, fuse_px=0.0)
    best: BranchStart | None = None
    for trio in _widest_triples(places)[:TRUNK_TRIANGLES]:
        for assigned in _fitting_triples(trio, apart, low, high, support):
            goal = np.full((markers, 3), np.nan)
            goal[list(trio)] = candidates.points[assigned]
            posture = _kernels.refine(q, bounds, kin, rig.arrays, image, np.inf, TRUNK_IK_STEPS, goal)
            error = float(_kernels.posture_error(posture, kin, rig.arrays, image))
            if best is None or error < best.error:
                best = BranchStart(posture, error, 3)
    return best


def _widest_triples(places: np.ndarray) -> list[tuple[int, int, int]]:
    """Every three of the markers at ``places`` (m, 3), widest triangle first (stable)."""
    trios = [(a, b, c) for a in range(len(places)) for b in range(a + 1, len(places))
             for c in range(b + 1, len(places))]
    area = [float(np.linalg.norm(np.cross(places[b] - places[a], places[c] - places[a])))
            for a, b, c in trios]
    return [trios[i] for i in np.argsort(-np.array(area), kind="stable")]


def _fitting_triples(trio: tuple[int, int, int], apart: np.ndarray, low: np.ndarray, high: np.ndarray,
                     support: np.ndarray) -> np.ndarray:
    """(n, 3) int, n at most :data:`MAX_TRIPLES`: candidates (indices) that may be the markers
    ``trio``, distinct, each two at a distance (``apart`` (K, K)) within the markers' interval
    (``low``, ``high``); gathered from the pairs of the first two that more views support
    (summed ``support`` (K,)) first, most supported triples first."""
    a, b, c = trio

    def fits(x: int, y: int) -> np.ndarray:
        ok = (apart >= low[x, y]) & (apart <= high[x, y])
        np.fill_diagonal(ok, False)
        return ok

    ab, ac, bc = fits(a, b), fits(a, c), fits(b, c)
    i, j = np.nonzero(ab)
    rows: list[tuple[int, int, int]] = []
    for k in np.argsort(-(support[i] + support[j]), kind="stable"):
        if len(rows) >= MAX_TRIPLES:
            break
        x, y = int(i[k]), int(j[k])
        rows += [(x, y, int(z)) for z in np.flatnonzero(ac[x] & bc[y])]
    out = np.array(rows[:MAX_TRIPLES], dtype=np.int64).reshape(-1, 3)
    return out[np.argsort(-support[out].sum(axis=1), kind="stable")]


def _markers(q: np.ndarray, kin: KinematicArrays) -> np.ndarray:
    """(M, 3) world marker positions of the part posed at ``q``."""
    return _kernels.marker_positions_many(q[None], kin)[0]


def _doubt(n_views: np.ndarray) -> np.ndarray:
    """(K,) in [0, 1): the share of views that could support a candidate and do not, taking the
    best supported candidate's views as those that see the branch. A ghost pairs with a blob
    of one other view by chance; a marker is seen by every view that sees the branch.

    >>> _doubt(np.array([6, 2, 3]))
    array([0.        , 0.66666667, 0.5       ])
    """
    return 1.0 - n_views / n_views.max()


_BOUNDS: WeakKeyDictionary[Part, dict[tuple[bytes, bytes], tuple[np.ndarray, np.ndarray]]] = (
    WeakKeyDictionary())


def _part_bounds(part: Part, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_distance_bounds` of ``part`` within the DOF ranges ``lower``, ``upper`` (d,), widened
    by :data:`SLACK_FRACTION` of its reach, computed once per part and ranges: distances
    between its markers and its base origin do not depend on where the base is, and the
    512 sampled postures cost a twelfth of a two-camera hexapod image's triangulated starts."""
    per_part = _BOUNDS.setdefault(part, {})
    key = (lower.tobytes(), upper.tobytes())
    if key not in per_part:
        per_part[key] = _distance_bounds(part.kin, lower, upper, SLACK_FRACTION * part.reach)
    return per_part[key]


def _distance_bounds(kin: KinematicArrays, lower: np.ndarray, upper: np.ndarray,
                     slack: float) -> tuple[np.ndarray, np.ndarray]:
    """(M + 1, M + 1) least and greatest distance (model units) between markers, the base
    origin last, over :data:`SAMPLES` postures of the R_d low-discrepancy sequence through the
    DOF ranges, widened by ``slack``."""
    d = len(lower)
    phi = 2.0
    for _ in range(32):  # the generalised golden ratio: phi^(d + 1) = phi + 1
        phi = (1.0 + phi) ** (1.0 / (d + 1))
    alpha = phi ** -np.arange(1.0, d + 1)
    unit = (0.5 + np.arange(1, SAMPLES + 1)[:, None] * alpha) % 1.0
    world = _kernels.marker_positions_many(lower + unit * (upper - lower), kin)
    base = np.broadcast_to(kin.offset[0], (SAMPLES, 1, 3))
    world = np.concatenate([world, base], axis=1)
    dist = np.linalg.norm(world[:, :, None] - world[:, None], axis=3)
    return dist.min(axis=0) - slack, dist.max(axis=0) + slack
