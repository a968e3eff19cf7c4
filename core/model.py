"""Kinematic model: joints with Euler DOFs, segments and markers (paper §2.1, FORMATS §1).

A model is parsed once from ``model.xml``, validated (every mistake is one
:class:`ModelError` naming the element), and turned into flat float64 arrays
(:class:`KinematicArrays`) that the compiled kernels read. Forward kinematics
follows the spec exactly::

    W_j = W_parent · T(offset_j [+ t]) · R(rest_j) · R(dof angles_j),
    R(y, x, z) = Ry(y) · Rx(x) · Rz(z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple
from xml.etree.ElementTree import Element

import numpy as np

from core import _kernels
from core._files import decimal, parse_decimal
from core.xmlio import attribute, parse

if TYPE_CHECKING:
    from core.identifiability import Identifiability
    from core.tree import Tree

__all__ = [
    "MAX_ABS_VALUE", "MAX_JOINTS", "MAX_MARKERS", "Dof", "Joint", "KinematicArrays", "KinematicModel",
    "Marker", "ModelError",
]

ROTATION_AXES = ("x", "y", "z")
TRANSLATION_AXES = ("tx", "ty", "tz")
# Column of an axis in KinematicArrays.rot_dof (composition order Ry·Rx·Rz).
_ROT_SLOT = {"y": 0, "x": 1, "z": 2}
_TRANS_SLOT = {"tx": 0, "ty": 1, "tz": 2}

# Defaults of the ``max_joints`` and ``max_markers`` options of ``from_xml``: ten times a
# whole-body model with fingers. Fitting costs time per marker, so a service should not go
# much higher; forward kinematics and validation are iterative and work at any size.
MAX_JOINTS = 1000
MAX_MARKERS = 1000
# Largest magnitude of a number in a model file: offsets and marker positions (model units),
# angles (degrees). With it every world position stays finite whatever the posture.
MAX_ABS_VALUE = 1e6


class ModelError(ValueError):
    """A model file that cannot be used; the message names the element and the problem."""


@dataclass(frozen=True)
class Dof:
    """One free degree of freedom: a rotation (degrees) or a root translation (model units)."""

    name: str
    joint: str
    axis: str
    min: float
    max: float

    @property
    def rotational(self) -> bool:
        return self.axis in ROTATION_AXES


@dataclass(frozen=True)
class Joint:
    """A joint frame: ``offset`` from the parent origin (parent frame), ``rest`` Euler degrees."""

    name: str
    parent: str | None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rest: dict[str, float] = field(default_factory=lambda: {"y": 0.0, "x": 0.0, "z": 0.0})


@dataclass(frozen=True)
class Marker:
    """A marker at ``position`` (model units) in the frame of ``joint``."""

    name: str
    joint: str
    position: tuple[float, float, float]


class KinematicArrays(NamedTuple):
    """The model as contiguous arrays for the numba kernels; joints in topological order.

    parent : (J,) int64, topological index of the parent, -1 for the root.
    offset : (J, 3) float64, model units, parent frame.
    rest : (J, 3, 3) float64, rest rotation matrix R(rest).
    rest_identity : (J,) bool, True where R(rest) is the identity (skipped by the kernels).
    rot_dof : (J, 3) int64, DOF index of the y, x, z angle (composition order), -1 if locked.
    trans_dof : (J, 3) int64, DOF index of tx, ty, tz (root only), -1 if none.
    marker_joint : (M,) int64, topological joint index of each marker.
    marker_pos : (M, 3) float64, model units, joint frame.
    """

    parent: np.ndarray
    offset: np.ndarray
    rest: np.ndarray
    rest_identity: np.ndarray
    rot_dof: np.ndarray
    trans_dof: np.ndarray
    marker_joint: np.ndarray
    marker_pos: np.ndarray


@dataclass(frozen=True)
class KinematicModel:
    """A validated kinematic tree. Build it with :meth:`from_xml`; DOFs keep model-file order."""

    name: str
    units: str
    joints: tuple[Joint, ...]
    dofs: tuple[Dof, ...]
    markers: tuple[Marker, ...]

    def __post_init__(self) -> None:
        _validate_model(self)

    # ---- reading and writing -------------------------------------------------
    @classmethod
    def from_xml(
        cls, source: str | bytes | Path, *, max_joints: int = MAX_JOINTS, max_markers: int = MAX_MARKERS
    ) -> KinematicModel:
        """Parse and validate ``model.xml`` given as text, bytes or a path.

        ``max_joints`` and ``max_markers`` refuse models larger than a lab would use
        (see :data:`MAX_JOINTS`); the XML itself is bounded by the ``MAX_XML_*`` limits of
        :mod:`core.xmlio`.
        """
        root = parse(source, "model file", ModelError)
        if root.tag != "model":
            raise ModelError(f"root element is <{root.tag}>, expected <model>")
        _check_count(root, "joint", max_joints)
        _check_count(root, "marker", max_markers)
        joints, dofs = [], []
        for el in root.findall("joint"):
            joint, joint_dofs = _joint_from_element(el)
            joints.append(joint)
            dofs.extend(joint_dofs)
        markers = [_marker_from_element(el) for el in root.findall("marker")]
        unknown = sorted({el.tag for el in root} - {"joint", "marker"})
        if unknown:
            raise ModelError(f"<model> contains unknown element <{unknown[0]}>")
        return cls(
            name=root.get("name", "model"),
            units=root.get("units", "mm"),
            joints=tuple(joints),
            dofs=tuple(dofs),
            markers=tuple(markers),
        )

    def to_xml(self) -> str:
        """The model as ``model.xml`` text (FORMATS §1); ``from_xml(to_xml())`` is identity."""
        lines = [f'<model name="{attribute(self.name)}" units="{attribute(self.units)}">']
        for joint in self.joints:
            parent = f' parent="{attribute(joint.parent)}"' if joint.parent is not None else ""
            lines.append(f'  <joint name="{attribute(joint.name)}"{parent}>')
            x, y, z = joint.offset
            lines.append(f'    <offset x="{decimal(x)}" y="{decimal(y)}" z="{decimal(z)}"/>')
            r = joint.rest
            lines.append(f'    <rest y="{decimal(r["y"])}" x="{decimal(r["x"])}" z="{decimal(r["z"])}"/>')
            for dof in self.dofs:
                if dof.joint == joint.name:
                    lines.append(
                        f'    <dof axis="{dof.axis}" name="{attribute(dof.name)}" '
                        f'min="{decimal(dof.min)}" max="{decimal(dof.max)}"/>'
                    )
            lines.append("  </joint>")
        for m in self.markers:
            x, y, z = m.position
            lines.append(
                f'  <marker name="{attribute(m.name)}" joint="{attribute(m.joint)}" '
                f'x="{decimal(x)}" y="{decimal(y)}" z="{decimal(z)}"/>'
            )
        lines.append("</model>")
        return "\n".join(lines) + "\n"

    # ---- derived views ---------------------------------------------------------
    @property
    def dof_names(self) -> list[str]:
        return [d.name for d in self.dofs]

    @cached_property
    def lower(self) -> np.ndarray:
        """(D,) float64: each DOF's ``min``."""
        return np.array([d.min for d in self.dofs], dtype=np.float64)

    @cached_property
    def upper(self) -> np.ndarray:
        """(D,) float64: each DOF's ``max`` (may exceed 360 for ranges that wrap)."""
        return np.array([d.max for d in self.dofs], dtype=np.float64)

    @cached_property
    def rotational(self) -> np.ndarray:
        """(D,) bool: True for angle DOFs, False for root translations."""
        return np.array([d.rotational for d in self.dofs], dtype=bool)

    @cached_property
    def arrays(self) -> KinematicArrays:
        """The model as flat arrays for the kernels (joints in topological order)."""
        return _build_arrays(self)

    @cached_property
    def tree(self) -> Tree | None:
        """Trunk and branches for part-by-part fitting, None to fit as a whole (``core.tree``)."""
        from core.tree import decompose  # core.tree builds on this module's arrays

        return decompose(self)

    @cached_property
    def identifiability(self) -> Identifiability:
        """DOFs the markers cannot determine in any posture, and what would (``core.identifiability``)."""
        from core.identifiability import identifiability  # builds on marker_positions

        return identifiability(self)

    # ---- forward kinematics ------------------------------------------------------
    def marker_positions(self, dofs: np.ndarray) -> np.ndarray:
        """World marker positions for one posture or many.

        Parameters
        ----------
        dofs : ndarray of shape (D,) or (T, D), float64
            DOF values in model-file order: degrees, model units for translations.

        Returns
        -------
        ndarray of shape (M, 3) or (T, M, 3), float64, model units, world frame.
        """
        q = self._check_postures(dofs)
        out = _kernels.marker_positions_many(q, self.arrays)
        return out[0] if np.ndim(dofs) == 1 else out

    def joint_transforms(self, dofs: np.ndarray) -> np.ndarray:
        """World transforms W_j (4×4) of every joint, in model-file joint order.

        Parameters
        ----------
        dofs : ndarray of shape (D,), float64, one posture.

        Returns
        -------
        ndarray of shape (J, 4, 4), float64.
        """
        if np.ndim(dofs) != 1:
            raise ValueError(f"dofs must have shape (D,) with D={len(self.dofs)}, got {np.shape(dofs)}")
        q = self._check_postures(dofs)[0]
        rot = np.empty((len(self.joints), 3, 3))
        pos = np.empty((len(self.joints), 3))
        _kernels.forward_kinematics(q, self.arrays, rot, pos)
        w = np.zeros((len(self.joints), 4, 4))
        w[:, :3, :3], w[:, :3, 3], w[:, 3, 3] = rot, pos, 1.0
        return w[np.argsort(self._topological_order)]

    @cached_property
    def _topological_order(self) -> np.ndarray:
        return np.array(_topological_order(self.joints), dtype=np.int64)

    def _check_postures(self, dofs: np.ndarray) -> np.ndarray:
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(dofs, dtype=np.float64)))
        if np.ndim(dofs) == 0 or q.ndim != 2 or q.shape[1] != len(self.dofs):
            raise ValueError(
                f"dofs must have shape (D,) or (T, D) with D={len(self.dofs)}, got {np.shape(dofs)}"
            )
        return q


# ---- parsing helpers ---------------------------------------------------------------


def _check_count(root: Element, tag: str, limit: int) -> None:
    count = len(root.findall(tag))
    if count > limit:
        raise ModelError(f"model has {count} <{tag}> elements; at most {limit} are allowed (max_{tag}s)")


def _number(el: Element, attr: str, where: str, default: float | None = None) -> float:
    raw = el.get(attr)
    if raw is None:
        if default is None:
            raise ModelError(f"{where}: missing attribute '{attr}'")
        return default
    try:
        value = parse_decimal(raw)
    except ValueError:
        raise ModelError(f"{where}: attribute {attr}={raw!r} is not a number") from None
    if not math.isfinite(value):
        raise ModelError(f"{where}: attribute {attr}={raw!r} is not a finite number")
    if abs(value) > MAX_ABS_VALUE:
        raise ModelError(f"{where}: attribute {attr}={raw!r} is beyond ±{MAX_ABS_VALUE:g} (MAX_ABS_VALUE)")
    return value


def _xyz(el: Element | None, where: str) -> tuple[float, float, float]:
    if el is None:
        return (0.0, 0.0, 0.0)
    return tuple(_number(el, a, where, 0.0) for a in "xyz")  # type: ignore[return-value]


def _joint_from_element(el: Element) -> tuple[Joint, list[Dof]]:
    name = el.get("name")
    if not name:
        raise ModelError("<joint> without a name attribute")
    where = f"joint '{name}'"
    offset = _xyz(el.find("offset"), f"{where} <offset>")
    rest_el = el.find("rest")
    rest = {a: 0.0 for a in "yxz"}
    if rest_el is not None:
        rest = {a: _number(rest_el, a, f"{where} <rest>", 0.0) for a in "yxz"}
    dofs = []
    for d in el.findall("dof"):
        dname = d.get("name")
        if not dname:
            raise ModelError(f"{where}: <dof> without a name attribute")
        dwhere = f"{where} dof '{dname}'"
        axis = d.get("axis", "")
        if axis not in ROTATION_AXES + TRANSLATION_AXES:
            raise ModelError(f"{dwhere}: unknown axis {axis!r} (expected x, y, z, tx, ty or tz)")
        dofs.append(
            Dof(dname, name, axis, _number(d, "min", dwhere), _number(d, "max", dwhere))
        )
    joint = Joint(name=name, parent=el.get("parent") or None, offset=offset, rest=rest)
    return joint, dofs


def _marker_from_element(el: Element) -> Marker:
    name = el.get("name")
    if not name:
        raise ModelError("<marker> without a name attribute")
    joint = el.get("joint")
    if not joint:
        raise ModelError(f"marker '{name}': missing attribute 'joint'")
    return Marker(name, joint, _xyz(el, f"marker '{name}'"))


# ---- validation --------------------------------------------------------------------


def _validate_model(model: KinematicModel) -> None:
    _check_unique("joint", [j.name for j in model.joints])
    _check_unique("dof", [d.name for d in model.dofs])
    _check_unique("marker", [m.name for m in model.markers])
    names = {j.name for j in model.joints}
    if not model.joints:
        raise ModelError("model has no <joint>")
    for j in model.joints:
        if j.parent is not None and j.parent not in names:
            raise ModelError(f"joint '{j.name}': parent '{j.parent}' is not a joint of this model")
    roots = [j.name for j in model.joints if j.parent is None]
    if len(roots) != 1:
        raise ModelError(
            "model has no root joint (every joint has a parent)"
            if not roots
            else f"model has {len(roots)} root joints ({', '.join(roots)}); exactly one is allowed"
        )
    _topological_order(model.joints)  # raises on a cycle
    # DOF order is the posture layout; model.xml nests dofs in joints, so only joint-by-joint
    # order survives to_xml/from_xml (models built in code could break it).
    position = {j.name: i for i, j in enumerate(model.joints)}
    last = 0
    for d in model.dofs:
        if d.joint not in position:
            raise ModelError(f"dof '{d.name}': joint '{d.joint}' is not a joint of this model")
        if position[d.joint] < last:
            raise ModelError(f"dof '{d.name}': dofs must be listed joint by joint, in joint order")
        last = position[d.joint]
    for d in model.dofs:
        _validate_dof(d, root=roots[0])
    seen: set[tuple[str, str]] = set()
    for d in model.dofs:
        if (d.joint, d.axis) in seen:
            raise ModelError(f"joint '{d.joint}': two dofs on axis '{d.axis}'")
        seen.add((d.joint, d.axis))
    for m in model.markers:
        if m.joint not in names:
            raise ModelError(f"marker '{m.name}': joint '{m.joint}' is not a joint of this model")
    if not model.markers:
        raise ModelError("model has no <marker>: nothing could be fitted")
    if not model.dofs:
        raise ModelError("model has no <dof>: there is no posture to fit")


def _validate_dof(d: Dof, root: str) -> None:
    where = f"joint '{d.joint}' dof '{d.name}'"
    if d.min >= d.max:
        raise ModelError(f"{where}: min={decimal(d.min)} must be smaller than max={decimal(d.max)}")
    if not d.rotational and d.joint != root:
        raise ModelError(f"{where}: translational axis '{d.axis}' is only allowed on the root joint")
    if d.rotational and d.max - d.min > 360.0:
        raise ModelError(f"{where}: range {decimal(d.min)}..{decimal(d.max)} spans more than 360 degrees")


def _check_unique(kind: str, names: list[str]) -> None:
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise ModelError(f"duplicate {kind} name '{n}'")
        seen.add(n)


def _topological_order(joints: tuple[Joint, ...]) -> list[int]:
    """Indices of ``joints`` with every parent before its children; raises on a cycle."""
    index = {j.name: i for i, j in enumerate(joints)}
    children: dict[int, list[int]] = {i: [] for i in range(len(joints))}
    roots = []
    for i, j in enumerate(joints):
        if j.parent is None:
            roots.append(i)
        else:
            children[index[j.parent]].append(i)
    order: list[int] = []
    stack = list(reversed(roots))
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(reversed(children[i]))
    if len(order) != len(joints):
        stuck = sorted(joints[i].name for i in set(range(len(joints))) - set(order))
        raise ModelError(f"joints {', '.join(stuck)} form a cycle (no path to the root)")
    return order


# ---- arrays for the kernels ------------------------------------------------------------


def _build_arrays(model: KinematicModel) -> KinematicArrays:
    order = _topological_order(model.joints)
    topo = {model.joints[i].name: k for k, i in enumerate(order)}
    n = len(order)
    parent = np.full(n, -1, dtype=np.int64)
    offset = np.zeros((n, 3))
    rest = np.zeros((n, 3, 3))
    rot_dof = np.full((n, 3), -1, dtype=np.int64)
    trans_dof = np.full((n, 3), -1, dtype=np.int64)
    for k, i in enumerate(order):
        j = model.joints[i]
        parent[k] = -1 if j.parent is None else topo[j.parent]
        offset[k] = j.offset
        rest[k] = euler_matrix(j.rest["y"], j.rest["x"], j.rest["z"])
    for di, d in enumerate(model.dofs):
        if d.rotational:
            rot_dof[topo[d.joint], _ROT_SLOT[d.axis]] = di
        else:
            trans_dof[topo[d.joint], _TRANS_SLOT[d.axis]] = di
    marker_joint = np.array([topo[m.joint] for m in model.markers], dtype=np.int64)
    marker_pos = np.array([m.position for m in model.markers], dtype=np.float64).reshape(-1, 3)
    rest_identity = np.array([np.array_equal(r, np.eye(3)) for r in rest], dtype=bool)
    return KinematicArrays(
        parent, offset, rest, rest_identity, rot_dof, trans_dof, marker_joint, marker_pos
    )


def euler_matrix(y: float, x: float, z: float) -> np.ndarray:
    """R(y, x, z) = Ry(y)·Rx(x)·Rz(z) for angles in degrees (FORMATS §1).

    >>> np.round(euler_matrix(0, 0, 90) @ [1, 0, 0], 12).tolist()
    [0.0, 1.0, 0.0]
    """
    out = np.empty((3, 3))
    _kernels.euler_matrix(math.radians(y), math.radians(x), math.radians(z), out)
    return out
