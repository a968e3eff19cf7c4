"""Hand-made trees for the tests: an insect-like body with legs, pinhole cameras around it.

Every leg has 5 DOFs (coxa yaw, roll, pitch; femur levation; knee) and 4 markers (coxa,
femur, tibia, claw); the thorax has 3 markers and, optionally, DOFs of its own.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np

from core.error import Detections
from core.model import KinematicModel
from core.rig import Rig

FREE_ROOT = (
    '<dof axis="tx" name="tx" min="-30" max="30"/><dof axis="ty" name="ty" min="-20" max="20"/>'
    '<dof axis="tz" name="tz" min="-5" max="5"/><dof axis="y" name="pitch" min="-20" max="20"/>'
    '<dof axis="x" name="roll" min="-20" max="20"/><dof axis="z" name="heading" min="-60" max="60"/>'
)


def insect(legs: int = 2, root_dofs: str = "", thorax_markers: int = 3,
           attach: list[tuple[float, float]] | None = None) -> KinematicModel:
    """A thorax with ``legs`` legs, attached at ``attach`` (x, y) or alternately left and right
    at x = 12, 0, -12 mm; ``root_dofs``: the thorax's own <dof> elements."""
    if attach is None:
        xs = [12.0, 0.0, -12.0]
        attach = [(xs[k // 2], 3.0 if k % 2 == 0 else -3.0) for k in range(legs)]
    out = ['<model name="insect" units="mm">', f'<joint name="thorax">{root_dofs}</joint>']
    for k, (x, y) in enumerate(attach):
        out += _leg(f"leg{k}", "thorax", x, y)
    thorax = [(14, 0, 1), (-14, 0, 1), (0, 2, 3)][:thorax_markers]
    out += [f'<marker name="T{i}" joint="thorax" x="{x}" y="{y}" z="{z}"/>'
            for i, (x, y, z) in enumerate(thorax)]
    return KinematicModel.from_xml("\n".join([*out, "</model>"]))


def tail(segments: int, legs: int = 0, axes: str = "zy") -> KinematicModel:
    """A fixed thorax (3 markers) with a tail of ``segments`` joints behind it (4 mm apart,
    yaw ±30° and pitch ±20° each, or those of ``axes``; a marker at each one's end: at the
    origin of the joint below) and ``legs`` of the insect's legs."""
    out = ['<model name="tail" units="mm">', '<joint name="thorax"></joint>']
    parent = "thorax"
    for k in range(segments):
        dofs = {"z": f'<dof axis="z" name="t{k}_yaw" min="-30" max="30"/>',
                "y": f'<dof axis="y" name="t{k}_pitch" min="-20" max="20"/>'}
        out.append(f'<joint name="t{k}" parent="{parent}"><offset x="{-4 if k else -14}" y="0" z="0"/>'
                   + "".join(dofs[a] for a in axes) + "</joint>")
        parent = f"t{k}"
    out.append(f'<joint name="tip" parent="{parent}"><offset x="-4" y="0" z="0"/></joint>')
    ends = [f"t{k}" for k in range(1, segments)] + ["tip"]
    out += [f'<marker name="tail{k}" joint="{j}" x="0" y="0" z="0"/>' for k, j in enumerate(ends)]
    for k in range(legs):
        out += _leg(f"leg{k}", "thorax", 12.0 - 12.0 * (k // 2), 3.0 if k % 2 == 0 else -3.0)
    out += [f'<marker name="T{i}" joint="thorax" x="{x}" y="{y}" z="{z}"/>'
            for i, (x, y, z) in enumerate([(14, 0, 1), (-10, 0, 1), (0, 2, 3)])]
    return KinematicModel.from_xml("\n".join([*out, "</model>"]))


def backbone(vertebrae: int, limbs: bool = False) -> KinematicModel:
    """A fixed pelvis (3 markers) with a chain of ``vertebrae`` joints 5 mm apart, each
    turning three ways (±15°) and carrying two markers off its axis, 1.5 mm to either side;
    with ``limbs``, two of the insect's legs on the pelvis and two on the last vertebra."""
    out = ['<model name="backbone" units="mm">', '<joint name="pelvis"></joint>']
    if limbs:
        out += _leg("leg0", "pelvis", -3.0, 3.0) + _leg("leg1", "pelvis", -3.0, -3.0)
    parent = "pelvis"
    for k in range(vertebrae):
        out.append(f'<joint name="v{k}" parent="{parent}"><offset x="5" y="0" z="0"/>'
                   + "".join(f'<dof axis="{a}" name="v{k}_{a}" min="-15" max="15"/>' for a in "zyx")
                   + "</joint>")
        out += [f'<marker name="v{k}{side}" joint="v{k}" x="2.5" y="{1.5 * sign}" z="1"/>'
                for side, sign in (("L", 1), ("R", -1))]
        parent = f"v{k}"
    if limbs:
        out += _leg("arm0", parent, 0.0, 3.0) + _leg("arm1", parent, 0.0, -3.0)
    out += [f'<marker name="P{i}" joint="pelvis" x="{x}" y="{y}" z="{z}"/>'
            for i, (x, y, z) in enumerate([(-10, 0, 1), (0, 3, 2), (0, -3, 2)])]
    return KinematicModel.from_xml("\n".join([*out, "</model>"]))


SPINE_MARKERS = ((12.0, 0.0, 1.0), (8.0, 3.0, 2.0))


def vertebrate(root_dofs: str = "", spine_markers: tuple[tuple[float, float, float], ...] = SPINE_MARKERS,
               spine_dofs: str = "zxy") -> KinematicModel:
    """A tree that splits twice: a pelvis (3 markers) with two legs at x = -6 mm and a spine
    (4 mm ahead of it; rotations about ``spine_dofs``, ±25°; markers at ``spine_markers`` in
    its frame) whose end (16 mm along it) carries two arms. Legs and arms are the insect's
    legs (5 DOFs, 4 markers each)."""
    dof = {"z": "yaw", "x": "roll", "y": "pitch"}
    out = ['<model name="vertebrate" units="mm">', f'<joint name="pelvis">{root_dofs}</joint>']
    out += _leg("leg0", "pelvis", -6.0, 3.0) + _leg("leg1", "pelvis", -6.0, -3.0)
    out.append('<joint name="spine" parent="pelvis"><offset x="4" y="0" z="0"/>'
               + "".join(f'<dof axis="{a}" name="spine_{dof[a]}" min="-25" max="25"/>' for a in spine_dofs)
               + "</joint>")
    out.append('<joint name="shoulders" parent="spine"><offset x="16" y="0" z="0"/></joint>')
    out += _leg("arm0", "shoulders", 0.0, 3.0) + _leg("arm1", "shoulders", 0.0, -3.0)
    out += [f'<marker name="P{i}" joint="pelvis" x="{x}" y="{y}" z="{z}"/>'
            for i, (x, y, z) in enumerate([(-14, 0, 1), (-2, 3, 2), (-2, -3, 2)])]
    out += [f'<marker name="S{i}" joint="spine" x="{x}" y="{y}" z="{z}"/>'
            for i, (x, y, z) in enumerate(spine_markers)]
    return KinematicModel.from_xml("\n".join([*out, "</model>"]))


def _leg(n: str, parent: str, x: float, y: float) -> list[str]:
    """A leg ``n`` (5 DOFs, 4 markers) on joint ``parent`` at (x, y), pointing to the side of y."""
    s = 1 if y >= 0 else -1
    out = [
        f'<joint name="{n}_coxa" parent="{parent}"><offset x="{x}" y="{y}" z="0"/>'
        f'<rest y="0" x="0" z="{90 * s}"/>'
        f'<dof axis="z" name="{n}_yaw" min="-40" max="40"/>'
        f'<dof axis="x" name="{n}_roll" min="-30" max="30"/>'
        f'<dof axis="y" name="{n}_pitch" min="-40" max="20"/></joint>',
        f'<joint name="{n}_femur" parent="{n}_coxa"><offset x="3" y="0" z="0"/>'
        f'<dof axis="y" name="{n}_lev" min="-80" max="0"/></joint>',
        f'<joint name="{n}_tibia" parent="{n}_femur"><offset x="10" y="0" z="0"/>'
        f'<dof axis="y" name="{n}_knee" min="20" max="140"/></joint>',
        f'<joint name="{n}_claw" parent="{n}_tibia"><offset x="11" y="0" z="0"/></joint>',
    ]
    return out + [f'<marker name="{n}_{j}" joint="{n}_{j}" x="0" y="0" z="0"/>'
                  for j in ("coxa", "femur", "tibia", "claw")]


def ring_rig(cameras: int = 3, distance: float = 150.0, f: float = 900.0,
             size: tuple[int, int] = (640, 480), elevation_deg: float = 35.0,
             dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)) -> Rig:
    """``cameras`` pinhole cameras on a ring around the origin, looking at it, with OpenCV's
    distortion coefficients ``dist``."""
    views = []
    for c in range(cameras):
        az, el = 2 * math.pi * c / cameras + 0.3, math.radians(elevation_deg)
        eye = distance * np.array([math.cos(az) * math.cos(el), math.sin(az) * math.cos(el),
                                   math.sin(el)])
        forward = -eye / np.linalg.norm(eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        R = np.vstack([right, np.cross(forward, right), forward])
        views.append({"name": f"cam{c}", "video": c, "projection": {
            "type": "pinhole", "K": [[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1]],
            "dist": list(dist), "rvec": cv2.Rodrigues(R)[0].ravel().tolist(),
            "tvec": (-R @ eye).tolist()}})
    return Rig.from_json(json.dumps({"views": views}))


def movement(model: KinematicModel, n: int, seed: int = 0) -> np.ndarray:
    """(n, D) smooth postures: every DOF a sine within 10-90 % of its range."""
    rng = np.random.default_rng(seed)
    lo, hi = model.lower, model.upper
    phase = rng.uniform(0, 2 * np.pi, len(lo))
    return lo + (hi - lo) * (0.5 + 0.4 * np.sin(0.15 * np.arange(n)[:, None] + phase))


def detections(model: KinematicModel, rig: Rig, postures: np.ndarray, noise_px: float = 0.05,
               seed: int = 0) -> list[Detections]:
    """Every marker's projection plus Gaussian noise, one Detections per posture."""
    rng = np.random.default_rng(seed)
    proj = rig.project(model.marker_positions(np.atleast_2d(postures)))
    proj = proj + rng.normal(0.0, noise_px, proj.shape)
    return [Detections.from_views(list(p)) for p in proj]


def angle_errors(fitted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Absolute differences, angles the shorter way round (translations unaffected by <180)."""
    return np.abs((fitted - truth + 180.0) % 360.0 - 180.0)
