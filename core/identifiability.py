"""DOFs that a model's markers cannot determine in any posture: a structural null space.

A model may have DOFs that no image can fix, however clean: a root with six DOFs and no
marker of its own (tilting the pelvis about the line through both hip centres while both
hips flex back moves no marker), a wrist DOF with no hand marker, a roll about a segment's
axis when every marker below lies on that axis. They show as directions in which the
Jacobian J of the map DOFs → 3D marker positions (3M × D) is rank-deficient. A posture
can make J singular by itself (a straight knee lines up the markers of the shank), so a
direction counts only when J is rank-deficient at every sampled posture: the mid-range
one and :data:`RANDOM_POSTURES` seeded random ones within the DOF ranges
(:func:`structural_null_dofs`).

J is made dimensionless before its rank is taken, so that the test does not depend on the
model's units: translation columns are model units per model unit, rotation columns model
units per radian divided by the model's size (the RMS distance of the markers from their
centroid).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from core.model import KinematicModel, Marker, _topological_order

__all__ = ["MAX_ANALYSED_DOFS", "RANDOM_POSTURES", "Identifiability", "identifiability"]

RANDOM_POSTURES = 4  # seeded random postures sampled beside the mid-range one
# Models with more DOFs are not analysed: the cost grows as markers × DOFs² (the products
# JᵀJ) and DOFs³ (their eigenvectors), and a file may hold thousands of DOFs
# (docs/BENCH_SUBJECTS.md has the times).
MAX_ANALYSED_DOFS = 300
_FIX_TRIALS = 3  # segments, root first, tested for the marker that would fix the model
_SEED = 2026  # the random postures are the same on every call
_STEP_DEG = 1e-3  # central-difference step of J, degrees or model units × size
_RANK_TOL = 1e-5  # singular values below this × the largest count as zero
_INVOLVED = 1e-4  # a unit null direction with a component above this involves the DOF
# Direction of the tested marker from its joint: no coordinate axis, no diagonal.
_GENERIC = np.array([0.37, 0.56, 0.74]) / np.linalg.norm([0.37, 0.56, 0.74])


@dataclass(frozen=True)
class Identifiability:
    """What a model's markers leave undetermined in every posture (names in model-file order).

    undetermined : DOFs in a structural null direction; empty when the markers determine
        every DOF at a generic posture.
    unmarked : of those, the DOFs of segments (joints) with no marker on them or below:
        they move no marker at all.
    unmarked_segments : the deepest segment of each such chain: a marker there moves with
        every unmarked DOF above it.
    fix_segment : for the other undetermined DOFs, a segment where one marker (at a generic
        point, tested) would determine them; "" when none does or none is needed.
    analysed : False for a model of more than :data:`MAX_ANALYSED_DOFS` DOFs, not analysed
        (the rest is then empty).
    """

    undetermined: tuple[str, ...] = ()
    unmarked: tuple[str, ...] = ()
    unmarked_segments: tuple[str, ...] = ()
    fix_segment: str = ""
    analysed: bool = True

    def advice(self) -> str:
        """One line for the lab: which DOFs, and what would fix the model; "" when none.

        >>> Identifiability(("wrist",), ("wrist",), ("hand",)).advice()
        'wrist moves no marker: add a marker to segment hand'
        >>> Identifiability(("tilt", "hip"), fix_segment="pelvis").advice()
        'markers do not determine tilt, hip in any posture: a marker on segment pelvis would'
        """
        parts = []
        if self.unmarked:
            verb = "moves" if len(self.unmarked) == 1 else "move"
            plural = "s" if len(self.unmarked_segments) > 1 else ""
            parts.append(f"{', '.join(self.unmarked)} {verb} no marker: add a marker to "
                         f"segment{plural} {', '.join(self.unmarked_segments)}")
        rest = [d for d in self.undetermined if d not in self.unmarked]
        if rest:
            fix = f": a marker on segment {self.fix_segment} would" if self.fix_segment else ""
            parts.append(f"markers do not determine {', '.join(rest)} in any posture{fix}")
        return "; ".join(parts)


def identifiability(model: KinematicModel) -> Identifiability:
    """The structural null DOFs of ``model``, and what would fix them (cached on the model as
    ``model.identifiability``; about a millisecond for a 42-DOF model without any)."""
    if len(model.dofs) > MAX_ANALYSED_DOFS:
        return Identifiability(analysed=False)
    null = structural_null_dofs(model)
    if not null.any():
        return Identifiability()
    names = model.dof_names
    unmarked_joints = _unmarked_joints(model)
    unmarked = tuple(names[i] for i in np.flatnonzero(null) if model.dofs[i].joint in unmarked_joints)
    deepest = _deepest(model, unmarked_joints)
    rest = null & ~np.isin(names, unmarked)
    return Identifiability(tuple(names[i] for i in np.flatnonzero(null)), unmarked, deepest,
                           _fix_segment(model, rest, deepest) if rest.any() else "")


def structural_null_dofs(model: KinematicModel) -> np.ndarray:
    """(D,) bool: DOFs with a component in J's structural null space.

    Its dimension is the least nullity over the sampled postures; a posture with more has
    singular directions of its own (a straight knee, a hip at zero rotation that happens to
    leave adduction out of the null direction), so only the postures of least nullity,
    generic ones, say which DOFs the structural directions involve: any of them.
    """
    nulls = [null_space(scaled_jacobian(model, q)) for q in sample_postures(model)]
    least = min(n.shape[1] for n in nulls)
    involved = np.zeros(len(model.dofs), dtype=bool)
    if least == 0:
        return involved
    for null in (n for n in nulls if n.shape[1] == least):
        involved |= np.linalg.norm(null, axis=1) > _INVOLVED
    return involved


def sample_postures(model: KinematicModel) -> np.ndarray:
    """(1 + :data:`RANDOM_POSTURES`, D): the mid-range posture, then seeded uniform ones."""
    rng = np.random.default_rng(_SEED)
    mid = (model.lower + model.upper) / 2
    random = rng.uniform(model.lower, model.upper, (RANDOM_POSTURES, len(model.dofs)))
    return np.vstack([mid, random])


def scaled_jacobian(model: KinematicModel, q: np.ndarray) -> np.ndarray:
    """(3M, D) dimensionless Jacobian of the world marker positions at posture ``q`` (D,),
    rotation columns scaled by the model's size (:func:`model_size`)."""
    return marker_jacobian(model.marker_positions, q, model.rotational, model_size(model, q))


def marker_jacobian(positions: Callable[[np.ndarray], np.ndarray], q: np.ndarray,
                    rotational: np.ndarray, size: float) -> np.ndarray:
    """(3M, D) dimensionless Jacobian at posture ``q`` (D,) of the marker positions that
    ``positions`` gives for postures (n, D) as (n, M, 3), model units: central differences;
    translation columns per model unit, rotation columns (``rotational`` (D,) bool) per
    radian divided by ``size`` (model units), so that a rank test of it does not depend on
    the model's units."""
    D = len(q)
    # Per-DOF step: degrees for rotations, model units for translations, both small
    # against the model (a rotation of _STEP_DEG moves a marker size × 1.7e-5 at most).
    step = np.where(rotational, _STEP_DEG, _STEP_DEG * size)
    postures = np.repeat(q[None], 2 * D, axis=0)
    postures[:D] += np.diag(step)
    postures[D:] -= np.diag(step)
    moved = positions(postures).reshape(2 * D, -1)  # (2D, 3M)
    J = ((moved[:D] - moved[D:]) / (2 * step[:, None])).T
    per_unit = np.where(rotational, 180.0 / math.pi / size, 1.0)
    return J * per_unit[None, :]


def null_space(J: np.ndarray) -> np.ndarray:
    """(D, k) orthonormal basis of the directions J (rows × D) maps to (numerically) zero:
    singular values below :data:`_RANK_TOL` × the largest.

    From the eigenvectors of JᵀJ (D × D, eigenvalues the squared singular values): LAPACK's
    SVD of J itself is as exact but, on a loaded machine, orders of magnitude slower through
    its threaded QR (docs/BENCH_SUBJECTS.md has the times). Squaring costs precision, not
    the answer: the zero eigenvalues come out within about 1e-16 of the largest, the
    threshold is :data:`_RANK_TOL`² = 1e-10, and the bench subjects' smallest nonzero ones
    are above 6e-5 (singular values above 8e-3 of the largest)."""
    values, vectors = np.linalg.eigh(J.T @ J)  # ascending
    largest = float(values[-1]) if values.size else 0.0
    return np.asarray(vectors[:, values <= _RANK_TOL**2 * largest])


def model_size(model: KinematicModel, q: np.ndarray) -> float:
    """RMS distance (model units) of the markers at posture ``q`` from their centroid; the
    largest offset or marker position (or 1) when the markers coincide."""
    p = model.marker_positions(q)
    size = float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))
    if size > 0:
        return size
    lengths = [np.linalg.norm(j.offset) for j in model.joints]
    lengths += [np.linalg.norm(m.position) for m in model.markers]
    return float(max(lengths)) or 1.0


def _unmarked_joints(model: KinematicModel) -> tuple[str, ...]:
    """Joints with DOFs and no marker on them or below, in model-file order."""
    order = _topological_order(model.joints)
    parent = model.arrays.parent  # topological indices
    marked = np.zeros(len(order), dtype=bool)
    marked[model.arrays.marker_joint] = True
    for k in range(len(order) - 1, 0, -1):  # children after parents: leaves first
        marked[parent[k]] |= marked[k]
    with_dofs = {d.joint for d in model.dofs}
    unmarked = {model.joints[i].name for k, i in enumerate(order) if not marked[k]}
    return tuple(j.name for j in model.joints if j.name in unmarked and j.name in with_dofs)


def _deepest(model: KinematicModel, joints: tuple[str, ...]) -> tuple[str, ...]:
    """Those of ``joints`` with no other of them below."""
    parent = {j.name: j.parent for j in model.joints}
    above: set[str] = set()
    for name in joints:
        up = parent[name]
        while up is not None and up not in above:
            above.add(up)
            up = parent[up]
    return tuple(j for j in joints if j not in above)


def _fix_segment(model: KinematicModel, rest: np.ndarray, unmarked_segments: tuple[str, ...]) -> str:
    """The first segment, root first, of the DOFs ``rest`` ((D,) bool) on which one marker at
    a generic point (with one on each of ``unmarked_segments``) leaves none of them
    undetermined; "" when none of the first :data:`_FIX_TRIALS` does."""
    size = model_size(model, (model.lower + model.upper) / 2)
    x, y, z = (0.5 * size * _GENERIC).tolist()

    def marker(joint: str) -> Marker:
        return Marker(f"_test_{joint}", joint, (x, y, z))

    base = tuple(marker(j) for j in unmarked_segments)
    order = [model.joints[i].name for i in _topological_order(model.joints)]
    joints = {model.dofs[i].joint for i in np.flatnonzero(rest)}
    for joint in [j for j in order if j in joints][:_FIX_TRIALS]:
        trial = KinematicModel(model.name, model.units, model.joints, model.dofs,
                               (*model.markers, *base, marker(joint)))
        if not (structural_null_dofs(trial) & rest).any():
            return joint
    return ""
