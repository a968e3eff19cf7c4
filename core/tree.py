"""Whole animals: a kinematic tree split into parts fitted one after another (paper §4).

Annealing every DOF of a six-legged insect at once cannot work: the search space
grows with the product of the legs' spaces, while each leg's markers inform only
that leg. A kinematic tree decomposes. Walking down from the root while a joint
has a single child carrying markers (and DOFs) gives the **trunk**; the subtrees hanging
from the trunk's last joint (where it first splits) are the **branches**. Each
part is fitted by the paper's SA (Eq. 6 over its own DOFs, Eq. 5 over its own
markers, the histograms as constraints) with everything above it fixed, then the
whole posture is refined jointly. The cost of an image grows with the number of
branches, not with the product of their search spaces.

A branch that splits again is decomposed the same way, recursively: its own trunk (its
joints above its split) is fitted given its base, then each sub-branch given that trunk.
A human's upper body (lumbar, then head and two arms: 18 DOFs in ``bench/subjects/fullbody``)
is four parts of 3-6 DOFs, not one of 18. The parts come in fitting order, parents before
children; each knows its base, the joint whose world frame the parts before it have fixed.

The decomposition is read from the model alone. A single chain (the locust leg)
has no split, so it stays one part and is fitted exactly as before, unless it is long: a
chain of more than :data:`MAX_PART_DOFS` DOFs (a tail, a spine of many vertebrae), alone
on a fixed root, hanging as a branch or a branch's own trunk, is cut into segments fitted
one after another, each given the one above, where their markers fix them
(:func:`_segments`). The root's trunk with DOFs is fitted first only when its own markers
can fix its pose (at least three, or one for a trunk that only translates): otherwise the
whole tree is fitted at once. A branch's own trunk hangs from a fixed base, so counting
cannot say it: it is split off only where its markers fix its DOFs (:func:`_fixes`, a rank
test of their Jacobian; a rotation about a fixed point needs two markers not on one line
through it), else the branch is fitted whole. A branch's own trunk without DOFs is not a part
(its markers ride on the base); its sub-branches hang from its split.

A branch sees only the detections within its reach (the sphere its joints and
markers can sweep about its base, projected into each view, with a margin): the
other branches' blobs elsewhere in the image are not its business, and the
nearest-detection search stays short.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core import _kernels
from core.identifiability import marker_jacobian
from core.model import KinematicArrays, KinematicModel, _topological_order

__all__ = ["Part", "Tree", "decompose"]

REACH_MARGIN = 1.25  # a branch's projected reach is widened by this factor
# A chain (a branch, or a model on a fixed root that does not split) with more DOFs than
# this is cut into segments of at least SEGMENT_DOFS, each fitted given the one above
# (_segments): SA over one longer chain slows and misses (docs/BENCH_SUBJECTS.md,
# bench/chain.py).
MAX_PART_DOFS = 16
SEGMENT_DOFS = 4
FIX_POSTURES = 4  # postures at which a branch's own trunk must be fixed by its markers
# Least singular value of a branch trunk's Jacobian (reach per radian): a 1 degree change in
# its least determined direction moves its markers by 0.1 x reach x pi / 180 or more
# (0.5 mm for a 300 mm trunk).
FIX_SINGULAR = 0.1
_SPHERE = np.array(
    [[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)],
    dtype=np.float64,
)
_SPHERE /= np.linalg.norm(_SPHERE, axis=1, keepdims=True)
_AROUND = np.vstack([np.zeros(3), _SPHERE])  # the centre first


@dataclass(frozen=True, eq=False)  # compared and hashed by identity: a key of per-part caches
class Part:
    """A part of the tree fitted on its own.

    name : its top joint's name.
    joints : (j,) int64, topological indices (in the whole model) of the part's own joints,
        parents first; its base is not one of them.
    flips : (f,) int64, rows of ``kin`` whose joints the part's own depth-flip search flips
        (``core.treefit.tree_flip_alternatives``): those with rotational DOFs whose subtree
        holds no marker of another part. Empty for the root's trunk and for a branch's own
        trunk, whose flips carry other parts along (searched on the whole model).
    dofs : (d,) int64, indices into ``model.dofs`` (the part's posture layout).
    markers : (m,) int64, indices into ``model.markers``.
    base : topological index (in the whole model) of the fixed joint the part hangs from,
        -1 for the root's trunk. Its world frame is set by the parts fitted before.
    kin : the part alone as kernel arrays; for a part with a base, joint 0 is the base,
        whose world frame :meth:`at` sets per image.
    reach : model units, radius about the base origin that the part's markers can reach.
    """

    name: str
    joints: np.ndarray
    flips: np.ndarray
    dofs: np.ndarray
    markers: np.ndarray
    base: int
    kin: KinematicArrays
    reach: float

    def at(self, rotation: np.ndarray, origin: np.ndarray) -> KinematicArrays:
        """The part's arrays with its base joint at this world frame ((3, 3), (3,))."""
        if self.base < 0:
            return self.kin
        offset, rest, identity = self.kin.offset.copy(), self.kin.rest.copy(), self.kin.rest_identity.copy()
        offset[0], rest[0], identity[0] = origin, rotation, False
        return self.kin._replace(offset=offset, rest=rest, rest_identity=identity)


@dataclass(frozen=True)
class Tree:
    """A model's decomposition: its parts in fitting order, every part after the parts that
    hold the joints above its base (parents before children)."""

    parts: tuple[Part, ...]

    @property
    def trunk(self) -> Part | None:
        """The root's trunk (the part without a base), None when it has no DOFs."""
        return self.parts[0] if self.parts[0].base < 0 else None

    @property
    def branches(self) -> tuple[Part, ...]:
        """Every part hanging from a base, in fitting order: the parts that compete for blobs."""
        return tuple(p for p in self.parts if p.base >= 0)


@dataclass(frozen=True)
class _Topology:
    """What the decomposition reads of a model (J joints, topological order): each joint's
    children, ``below`` (J, J) (:func:`_subtrees`), ``carrying`` (J,) bool (a subtree with
    markers and DOFs) and ``dof_joint`` (D,) (each DOF's joint)."""

    children: list[list[int]]
    below: np.ndarray
    carrying: np.ndarray
    dof_joint: np.ndarray

    @classmethod
    def of(cls, model: KinematicModel) -> _Topology:
        topo = model.arrays
        J = len(model.joints)
        children: list[list[int]] = [[] for _ in range(J)]
        for k in range(1, J):
            children[topo.parent[k]].append(k)
        below = _subtrees(topo.parent)
        has_marker = np.zeros(J, dtype=bool)
        has_marker[topo.marker_joint] = True
        dof_joint = _dof_joints(model)
        has_dof = np.zeros(J, dtype=bool)
        has_dof[dof_joint] = True
        carrying = below[:, has_marker].any(axis=1) & below[:, has_dof].any(axis=1)
        return cls(children, below, carrying, dof_joint)

    def walk(self, top: int) -> tuple[list[int], list[int]]:
        """Walking down from joint ``top`` while a joint has a single carrying child: the
        joints walked, ``top`` first, and the carrying children of the last (none at a
        chain's end, two or more at a split)."""
        path = [top]
        while len(kids := [c for c in self.children[path[-1]] if self.carrying[c]]) == 1:
            path.append(kids[0])
        return path, kids

    def split(self, top: int) -> tuple[int, list[int]]:
        """The joint where :meth:`walk` from ``top`` stops, and its carrying children."""
        path, kids = self.walk(top)
        return path[-1], kids


def decompose(model: KinematicModel) -> Tree | None:
    """The parts of ``model`` in fitting order, or None when it is fitted as a whole.

    None for a single chain (no joint with two children carrying markers and DOFs)
    and for a root trunk whose DOFs its own markers cannot fix. Below the first split,
    each branch is decomposed again where it splits and its own trunk can be fitted
    given its base (:func:`_hanging`).

    >>> from core.examples import LOCUST
    >>> from core.model import KinematicModel
    >>> decompose(KinematicModel.from_xml(LOCUST / "model.xml")) is None
    True
    """
    topo = _Topology.of(model)
    split, kids = topo.split(0)
    if len(kids) < 2:
        return _root_chain(model, topo)
    in_branch = topo.below[kids].any(axis=0)
    trunk_part = _trunk(model, np.flatnonzero(~in_branch), topo.dof_joint)
    if trunk_part is False:
        return None
    parts = [trunk_part] if trunk_part is not None else []
    for c in kids:
        parts += _hanging(model, topo, split, c)
    return Tree(tuple(parts))


def _hanging(model: KinematicModel, topo: _Topology, base: int, top: int) -> list[Part]:
    """The parts, in fitting order, of the subtree from joint ``top`` hanging from joint
    ``base``: the subtree whole (one branch) unless it splits again and its own trunk (the
    joints above that split) either has no DOFs, or has markers that fix its DOFs given the
    base (:func:`_fixes`), or is a long chain cut into segments (:func:`_segments`); then
    that trunk (if it has DOFs) followed by each sub-branch's parts, hanging from the split.
    Where it never splits, a long chain is cut into segments too."""
    whole = [_branch(model, topo, base, np.flatnonzero(topo.below[top]))]
    split, kids = topo.split(top)
    if len(kids) < 2:
        return _segments(model, topo, base, top) or whole
    region = topo.below[top] & ~topo.below[kids].any(axis=0)
    own = np.flatnonzero(region)
    parts = []
    if np.isin(topo.dof_joint, own).any():
        segments = _segments(model, topo, base, top, region)
        if segments is None:
            segments = [_branch(model, topo, base, own)]
            if not _fixes(segments[0], model, topo):
                return whole
        parts += segments
    for c in kids:
        parts += _hanging(model, topo, split, c)
    return parts


def _root_chain(model: KinematicModel, topo: _Topology) -> Tree | None:
    """A model that never splits, as parts: None (fitted whole, as the paper's leg) unless
    it has more than :data:`MAX_PART_DOFS` DOFs, its root's own joint has none (a fixed
    body), and the chain below it cuts into segments (:func:`_segments`)."""
    if len(model.dofs) <= MAX_PART_DOFS or np.any(topo.dof_joint == 0):
        return None
    path = topo.walk(0)[0]
    parts = _segments(model, topo, 0, path[1]) if len(path) > 1 else None
    return Tree(tuple(parts)) if parts else None


def _segments(model: KinematicModel, topo: _Topology, base: int, top: int,
              region: np.ndarray | None = None) -> list[Part] | None:
    """A chain hanging from joint ``base`` from joint ``top`` with more than
    :data:`MAX_PART_DOFS` DOFs, cut into segments fitted one after another: the whole
    subtree of ``top`` where it never splits, or a branch's own trunk, the joints ``region``
    (J,) bool above its split, from which its sub-branches then hang. Each segment is the
    shortest run of the chain's joints, from where the one above ends, that has at least
    :data:`SEGMENT_DOFS` DOFs and whose markers fix them given its base (:func:`_fixes`); the
    last one takes the rest (at least :data:`SEGMENT_DOFS` DOFs), and must fix them too
    where sub-branches hang from it. None where the chain has no more DOFs than
    :data:`MAX_PART_DOFS` or it cannot be cut so.

    Why: SA over one chain's DOFs at once slows and misses as the chain grows
    (``bench/chain.py``, docs/BENCH_SUBJECTS.md). A segment's markers are
    those of its joints and those at the origin of the joint below its end, which only its
    DOFs move (:func:`_part_arrays`). Its cost: a segment whose end marker one camera alone
    sees is placed by that view alone, and the segments below cannot turn it back.
    """
    region = topo.below[top] if region is None else region
    path = topo.walk(top)[0]  # to the chain's end, or to the split under a branch's own trunk

    def dofs_in(joints: np.ndarray) -> int:
        return int(np.count_nonzero(np.isin(topo.dof_joint, np.flatnonzero(joints & region))))

    if dofs_in(topo.below[top]) <= MAX_PART_DOFS:
        return None
    parts: list[Part] = []
    start, at = 0, base
    for end in range(1, len(path)):
        joints = topo.below[path[start]] & ~topo.below[path[end]]
        if dofs_in(joints) < SEGMENT_DOFS:
            continue
        if dofs_in(topo.below[path[end]]) < SEGMENT_DOFS:
            break
        segment = _branch(model, topo, at, np.flatnonzero(joints & region), below=path[end],
                          above=path[start] if parts else -1)
        if _fixes(segment, model, topo):
            parts.append(segment)
            start, at = end, path[end - 1]
    if not parts:
        return None
    last = _branch(model, topo, at, np.flatnonzero(topo.below[path[start]] & region), above=path[start])
    if not region[topo.below[top]].all() and not _fixes(last, model, topo):
        return None
    return [*parts, last]


def _subtrees(parent: np.ndarray) -> np.ndarray:
    """(J, J) bool: ``[j, k]`` is True when k is j or lies below j (topological order)."""
    J = len(parent)
    below = np.eye(J, dtype=bool)
    for k in range(1, J):
        below[:, k] |= below[:, parent[k]]
    return below


def _dof_joints(model: KinematicModel) -> np.ndarray:
    """(D,) int64: topological index of each DOF's joint."""
    order = _topological_order(model.joints)
    topo = {model.joints[i].name: k for k, i in enumerate(order)}
    return np.array([topo[d.joint] for d in model.dofs], dtype=np.int64)


def _trunk(model: KinematicModel, joints: np.ndarray, dof_joint: np.ndarray) -> Part | bool | None:
    """The trunk (every joint in no branch) as a part; None without DOFs; False when its
    markers cannot fix its DOFs."""
    dofs = np.flatnonzero(np.isin(dof_joint, joints))
    if len(dofs) == 0:
        return None
    markers = np.flatnonzero(np.isin(model.arrays.marker_joint, joints))
    rotates = bool(model.rotational[dofs].any())
    if len(markers) < (3 if rotates else 1):
        return False
    kin = _part_arrays(model.arrays, joints, dofs, markers, base=-1)
    none = np.zeros(0, dtype=np.int64)
    return Part(_name(model, int(joints[0])), joints, none, dofs, markers, -1, kin, np.inf)


def _branch(model: KinematicModel, topo: _Topology, base: int, joints: np.ndarray,
            below: int = -1, above: int = -1) -> Part:
    """The joints ``joints`` hanging from joint ``base``, as a part with its base first. A
    chain's segment (:func:`_segments`) takes the markers at the origin of ``below``, the
    joint under its end, and leaves those at the origin of ``above``, its top joint, to the
    segment above."""
    dofs = np.flatnonzero(np.isin(topo.dof_joint, joints))
    marker_joint = model.arrays.marker_joint
    at_origin = ~model.arrays.marker_pos.any(axis=1)
    owned = (np.isin(marker_joint, joints) & ~((marker_joint == above) & at_origin)
             | (marker_joint == below) & at_origin)
    markers = np.flatnonzero(owned)
    kin = _part_arrays(model.arrays, joints, dofs, markers, base=base)
    others = np.delete(marker_joint, markers)
    rotating = np.isin(joints, topo.dof_joint[model.rotational])
    alone = ~topo.below[joints][:, others].any(axis=1)
    flips = 1 + np.flatnonzero(rotating & alone)  # rows of kin: the base, then the joints
    return Part(_name(model, int(joints[0])), joints, flips, dofs, markers, base, kin, _reach(kin))


def _fixes(part: Part, model: KinematicModel, topo: _Topology) -> bool:
    """Whether the markers of ``part`` (a branch's own trunk, or a run of a chain) fix its
    DOFs given its base frame: at each of :data:`FIX_POSTURES` postures (fixed draws
    through the middle 80 % of the DOF ranges), the Jacobian of its marker positions (3m, d)
    (``core.identifiability.marker_jacobian``: rotations per radian in units of the part's
    reach about its top joint, translations per model unit) has no singular value below
    :data:`FIX_SINGULAR` over its number of joints with DOFs.

    About its top joint, not its base: a chain's first joint may lie far from its base and
    turn markers near itself. Over its joints: along a chain of equal links the least
    singular value falls as the run grows, so a run that failed the plain threshold would
    only fail it more as it grew, and the chain would stay one part (docs/BENCH_SUBJECTS.md,
    "long chains cut into segments").

    Counting markers cannot say it for a chain of several joints: a rotation about the
    line through the base origin and a lone marker moves nothing, and two joints that each
    rotate three ways are not fixed by three markers on the second. The root's trunk keeps
    its count (:func:`_trunk`): nothing fixes its base.
    """
    d, reach = len(part.dofs), _reach(part.kin, top=1)
    if d == 0 or reach <= 0.0 or 3 * len(part.markers) < d:
        return False
    singular = FIX_SINGULAR / len(np.unique(topo.dof_joint[part.dofs]))
    lower, upper = model.lower[part.dofs], model.upper[part.dofs]
    unit = np.random.default_rng(0).uniform(0.1, 0.9, (FIX_POSTURES, d))

    def positions(postures: np.ndarray) -> np.ndarray:
        return _kernels.marker_positions_many(np.ascontiguousarray(postures), part.kin)

    for q in lower + unit * (upper - lower):
        jac = marker_jacobian(positions, q, model.rotational[part.dofs], reach)  # (3m, d)
        if np.linalg.svd(jac, compute_uv=False)[-1] < singular:
            return False
    return True


def _part_arrays(full: KinematicArrays, joints: np.ndarray, dofs: np.ndarray, markers: np.ndarray,
                 base: int) -> KinematicArrays:
    """Kernel arrays of ``joints`` (topological indices, parents first) with local DOF and
    joint indices; a base joint (identity frame until :meth:`Part.at`) first when ``base`` >= 0."""
    rows = np.concatenate([[base], joints]) if base >= 0 else joints
    local = {int(j): i for i, j in enumerate(rows)}
    n_dofs = int(max(full.rot_dof.max(initial=-1), full.trans_dof.max(initial=-1))) + 1
    dof_local = np.full(n_dofs + 1, -1, dtype=np.int64)  # index -1 (a locked axis) stays -1
    dof_local[dofs] = np.arange(len(dofs))
    parent = np.array([local.get(int(full.parent[j]), -1) for j in rows], dtype=np.int64)
    offset, rest = full.offset[rows].copy(), full.rest[rows].copy()
    identity = full.rest_identity[rows].copy()
    rot_dof = np.where(full.rot_dof[rows] >= 0, dof_local[full.rot_dof[rows]], -1)
    trans_dof = np.where(full.trans_dof[rows] >= 0, dof_local[full.trans_dof[rows]], -1)
    if base >= 0:
        parent[0] = -1
        offset[0], rest[0], identity[0] = 0.0, np.eye(3), True
        rot_dof[0], trans_dof[0] = -1, -1
    # a marker at the origin of the joint below a segment's end sits there on its parent
    joint = full.marker_joint[markers]
    outside = np.array([int(j) not in local for j in joint], dtype=bool)
    position = full.marker_pos[markers].copy().reshape(-1, 3)
    position[outside] = full.offset[joint[outside]]
    joint = np.where(outside, full.parent[joint], joint)
    marker_joint = np.array([local[int(j)] for j in joint], dtype=np.int64)
    return KinematicArrays(parent, offset, rest, identity, rot_dof.astype(np.int64),
                           trans_dof.astype(np.int64), marker_joint, position)


def _reach(kin: KinematicArrays, top: int = 0) -> float:
    """Upper bound on how far any marker of a branch lies from its base origin (model units),
    or from the origin of row ``top`` (1: the top joint under the base): the longest chain
    of offsets from there, plus the marker's own offset."""
    J = len(kin.parent)
    dist = np.zeros(J)
    for k in range(top + 1, J):
        dist[k] = dist[kin.parent[k]] + float(np.linalg.norm(kin.offset[k]))
    marker = dist[kin.marker_joint] + np.linalg.norm(kin.marker_pos, axis=1)
    return float(marker.max(initial=0.0))


def _name(model: KinematicModel, topo_index: int) -> str:
    return model.joints[_topological_order(model.joints)[topo_index]].name


def reach_points(origins: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(B, 27, 3) world points: each of B base ``origins`` (B, 3) and 26 points of the sphere
    of its branch's ``reach`` (B,) about it (widened by :data:`REACH_MARGIN`), whose
    projections bound where the branch's markers can appear in a view."""
    return origins[:, None] + (REACH_MARGIN * reach)[:, None, None] * _AROUND
