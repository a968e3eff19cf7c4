"""Write the benchmark subjects' model.xml and rig.json (FORMATS §1, §2) from published anatomy.

    python bench/subjects/build.py

Rewrites ``bench/subjects/hexapod/``, ``freefly/``, ``biped/``, ``fullbody/``, ``rat/``,
``mouse/`` and ``spider/``; the files are committed, this script says how they were made. Sources
and every number's origin:
``docs/BENCH_SUBJECTS.md``.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent

# ---- hexapod: Drosophila melanogaster, NeuroMechFly ---------------------------------------------

# Leg insertion points (thorax–coxa joints) and segment lengths in mm, read from NeuroMechFly's
# model (Lobato-Rios et al. 2022, Nature Methods 19:620-627; github.com/NeLy-EPFL/NeuroMechFly,
# data/design/sdf/neuromechfly_noLimits.sdf, link poses of the left legs; right legs mirror them).
# NeuroMechFly's frame is x forward, y left, z up; ours is x forward, y up, z right.
FLY_INSERTION_NMF = {"F": (0.418, 0.2700, 1.0800), "M": (0.0677, 0.1249, 0.6798),
                     "H": (-0.1477, 0.0870, 0.6072)}
# coxa, femur (incl. trochanter), tibia, tarsus (tarsomeres 1-4, to the origin of tarsomere 5).
FLY_SEGMENTS = {"F": (0.4255, 0.7052, 0.5184, 0.5647), "M": (0.1814, 0.7837, 0.6673, 0.6065),
                "H": (0.1994, 0.8363, 0.6845, 0.6978)}
# Plausible ranges (degrees) per leg pair, protraction and adduction positive on both sides (the
# left legs' files negate what mirrors). Set around NeuroMechFly's tripod pose
# (data/config/pose/pose_tripod.yaml) and its walking-data limits
# (data/design/sdf/neuromechfly_limitsFromData.sdf at commit eacdab4), widened to leave the search room.
FLY_RANGES = {
    "coxa_pro": {"F": (-10, 60), "M": (-35, 35), "H": (-60, 10)},
    "coxa_roll": (-30, 30),
    "coxa_abd": (-40, 20),
    "femur": (-140, -70),
    "femur_roll": (-30, 30),
    "tibia": (30, 150),
    "tarsus": (-80, -5),
}
FLY_THORAX_MARKERS = {"T0": (0.40, 1.30, 0.0), "T1": (-0.05, 1.25, -0.20), "T2": (-0.05, 1.25, 0.20)}
FLY_SIZE = (640, 480)


def _num(v: float) -> str:
    return np.format_float_positional(round(float(v), 4) + 0.0, trim="-")


def _xyz(tag: str, v) -> str:
    return f'<{tag} x="{_num(v[0])}" y="{_num(v[1])}" z="{_num(v[2])}"/>'


def _dof(axis: str, name: str, lo: float, hi: float) -> str:
    return f'<dof axis="{axis}" name="{name}" min="{_num(lo)}" max="{_num(hi)}"/>'


def _joint(name: str, parent: str | None, offset, dofs: list[str], rest=None) -> str:
    head = f'  <joint name="{name}"' + (f' parent="{parent}">' if parent else ">")
    body = ["    " + _xyz("offset", offset)]
    if rest is not None:
        body.append(f'    <rest y="{_num(rest[0])}" x="{_num(rest[1])}" z="{_num(rest[2])}"/>')
    body += ["    " + d for d in dofs]
    return "\n".join([head, *body, "  </joint>"])


def _marker(name: str, joint: str, pos=(0.0, 0.0, 0.0)) -> str:
    xyz = f'x="{_num(pos[0])}" y="{_num(pos[1])}" z="{_num(pos[2])}"'
    return f'  <marker name="{name}" joint="{joint}" {xyz}/>'


# The free fly's thorax (``freefly``): its ranges (mm, degrees) around the tethered pose.
FREE_THORAX = (("tx", "thorax_tx", 0.4), ("ty", "thorax_ty", 0.2), ("tz", "thorax_tz", 0.3),
               ("y", "thorax_yaw", 25.0), ("x", "thorax_roll", 10.0), ("z", "thorax_pitch", 12.0))


def hexapod_xml(free: bool = False) -> str:
    """42 DOFs: per leg coxa pro/roll/abd, femur, femur roll, tibia, tarsus; 4 markers per leg.
    ``free``: the thorax as well, 3 translations and 3 rotations (:data:`FREE_THORAX`; 48 DOFs)."""
    thorax = [_dof(axis, name, -r, r) for axis, name, r in FREE_THORAX] if free else []
    joints = [_joint("thorax", None, (0, 0, 0), thorax)]
    markers = [_marker(n, "thorax", p) for n, p in FLY_THORAX_MARKERS.items()]
    for side in "LR":
        s = 1.0 if side == "R" else -1.0
        for pair in "FMH":
            leg = side + pair
            x, y, z = FLY_INSERTION_NMF[pair]
            coxa, femur, tibia, tarsus = FLY_SEGMENTS[pair]
            pro = FLY_RANGES["coxa_pro"][pair]
            # Right legs: local x down, y inward, z forward (rest Ry(90)·Rz(-90)); a positive
            # rotation about local y moves the leg backward, so protraction is its negative.
            pro_lo, pro_hi = (-pro[1], -pro[0]) if side == "R" else pro
            joints += [
                _joint(f"{leg}_coxa", "thorax", (x, z, s * y),
                       [_dof("y", f"{leg}_coxa_pro", pro_lo, pro_hi),
                        _dof("x", f"{leg}_coxa_roll", *FLY_RANGES["coxa_roll"]),
                        _dof("z", f"{leg}_coxa_abd", *FLY_RANGES["coxa_abd"])],
                       rest=(90.0 * s, 0.0, -90.0)),
                _joint(f"{leg}_femur", f"{leg}_coxa", (coxa, 0, 0),
                       [_dof("z", f"{leg}_femur", *FLY_RANGES["femur"])]),
                _joint(f"{leg}_femur_roll", f"{leg}_femur", (0, 0, 0),
                       [_dof("x", f"{leg}_femur_roll", *FLY_RANGES["femur_roll"])]),
                _joint(f"{leg}_tibia", f"{leg}_femur_roll", (femur, 0, 0),
                       [_dof("z", f"{leg}_tibia", *FLY_RANGES["tibia"])]),
                _joint(f"{leg}_tarsus", f"{leg}_tibia", (tibia, 0, 0),
                       [_dof("z", f"{leg}_tarsus", *FLY_RANGES["tarsus"])]),
                _joint(f"{leg}_claw", f"{leg}_tarsus", (tarsus, 0, 0), []),
            ]
            markers += [_marker(f"{leg}_{m}", f"{leg}_{j}")
                        for m, j in (("CTr", "femur"), ("FTi", "tibia"), ("TiTa", "tarsus"),
                                     ("claw", "claw"))]
    head = ("A free fruit fly (Drosophila melanogaster): the thorax free (3 translations, yaw,\n"
            "       roll, pitch), six legs of" if free
            else "A tethered fruit fly (Drosophila melanogaster): the thorax is fixed, six legs of")
    comment = f"""  <!-- {head}
       7 DOFs (coxa protraction/roll/adduction, trochanter-femur flexion, femur roll, tibia,
       tarsus). Insertion points and segment lengths from NeuroMechFly (Lobato-Rios et al.
       2022, Nature Methods 19:620-627, neuromechfly_noLimits.sdf); ranges around its tripod
       pose and walking-data limits, widened. x forward, y up, z right; mm.
       Made by bench/subjects/build.py; docs/BENCH_SUBJECTS.md. -->"""
    name = "drosophila_free" if free else "drosophila_hexapod"
    return "\n".join([f'<model name="{name}" units="mm">', comment, *joints, *markers,
                      "</model>", ""])


def look_at(position, target, *, f: float, size: tuple[int, int], dist=(0, 0, 0, 0, 0)) -> dict:
    """A pinhole projection (OpenCV conventions) at ``position`` looking at ``target``, world y up."""
    p, t = np.asarray(position, float), np.asarray(target, float)
    z = (t - p) / np.linalg.norm(t - p)
    x = np.cross(z, (0.0, 1.0, 0.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.array([x, y, z])
    rvec = cv2.Rodrigues(R)[0].ravel()
    tvec = -R @ p
    w, h = size
    K = [[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]
    return {"type": "pinhole", "K": [[round(v, 4) for v in row] for row in K],
            "dist": list(dist), "rvec": [round(float(v), 6) for v in rvec],
            "tvec": [round(float(v), 6) for v in tvec]}


def ring(names, azimuths, *, radius, height, target, f, size, dist) -> dict:
    """Cameras around ``target`` (azimuth from +x towards +z, degrees) at ``radius`` from its
    vertical axis and at ``height``, each one for all or one per camera."""
    views = []
    radii = np.broadcast_to(np.asarray(radius, float), (len(names),))
    heights = np.broadcast_to(np.asarray(height, float), (len(names),))
    for i, (name, az, r, h) in enumerate(zip(names, azimuths, radii, heights, strict=True)):
        a = np.radians(az)
        pos = (target[0] + r * np.cos(a), h, target[2] + r * np.sin(a))
        views.append({"name": name, "video": i,
                      "projection": look_at(pos, target, f=f, size=size, dist=dist)})
    return {"views": views}


def hexapod_rig() -> dict:
    """Six cameras around the fly, 30° above it, 20 mm away (~110 px per mm), 640×480."""
    target = (0.1, 0.35, 0.0)
    return ring([f"cam{i}" for i in range(6)], [30, 90, 150, 210, 270, 330], radius=17.3,
                height=target[1] + 10.0, target=target, f=2200.0, size=FLY_SIZE,
                dist=(-0.05, 0.0, 0.0, 0.0, 0.0))


# ---- biped: human lower body, Plug-in Gait markers -----------------------------------------------

BODY_HEIGHT = 1750.0  # mm
# Segment lengths as fractions of body height (Drillis & Contini 1966, in Winter 2009,
# Biomechanics and Motor Control of Human Movement, 4th ed., Fig. 4.1).
THIGH, SHANK, ANKLE_HEIGHT = 0.245 * BODY_HEIGHT, 0.246 * BODY_HEIGHT, 0.039 * BODY_HEIGHT
FOOT = 0.152 * BODY_HEIGHT
# Hip joint centres from the ASIS (Bell, Pedersen & Brand 1990, J Biomech 23:617-621):
# 30 % of the inter-ASIS distance distal, 19 % posterior, 14 % medial. Inter-ASIS 250 mm.
ASIS_WIDTH = 250.0
HJC_FROM_ASIS = (-0.19 * ASIS_WIDTH, -0.30 * ASIS_WIDTH, 0.14 * ASIS_WIDTH)  # back, down, in
HIP_HALF_WIDTH = ASIS_WIDTH / 2 - HJC_FROM_ASIS[2]
# Joint ranges (American Academy of Orthopaedic Surgeons 1965, as tabulated by Roaas &
# Andersson 1982, Acta Orthop Scand 53:205-208): hip flexion 120, extension 30, abduction 45,
# adduction 30, internal and external rotation 45; knee flexion 135 (140 here); ankle
# dorsiflexion 20, plantar flexion 50.
BIPED_SIZE = (720, 576)


def _pelvis_joint(height: float, ranges: dict[str, tuple[float, float]]) -> str:
    """A pelvis root ``height`` above the floor with 3 translations and 3 rotations; ``ranges``
    by DOF name without the ``pelvis_`` prefix (tx, ty, tz, rotation, obliquity, tilt)."""
    axes = {"tx": "tx", "ty": "ty", "tz": "tz", "rotation": "y", "obliquity": "x", "tilt": "z"}
    return _joint("pelvis", None, (0, height, 0),
                  [_dof(axis, f"pelvis_{name}", *ranges[name]) for name, axis in axes.items()])


def _leg_joints(side: str, half_width: float, thigh: float, shank: float,
                ranges: dict[str, tuple[float, float]]) -> list[str]:
    """A leg's hip (flexion, adduction, rotation), knee and ankle joints on the pelvis, the hip
    ``half_width`` to the side: :func:`_limb_joints` named hip, knee, ankle."""
    s = 1.0 if side == "R" else -1.0
    return _limb_joints(side, ("hip", "knee", "ankle"), (0, 0, s * half_width), thigh, shank, ranges)


def _limb_joints(side: str, names: tuple[str, str, str], offset, upper: float, lower: float,
                 ranges: dict[str, tuple[float, float]]) -> list[str]:
    """A limb's proximal (flexion, adduction, rotation), middle and distal joints on the
    pelvis at ``offset``, ``names`` = (proximal, middle, distal) joint names without the side;
    ``ranges`` by DOF name without the side (``<proximal>_flexion``, ``_adduction``,
    ``_rotation``, ``<middle>_flexion``, ``<distal>_dorsiflexion``), adduction the right
    limb's (the left mirrors it).

    Local x down the upper segment, y forward, z to the right (rest Rz(-90)); a positive
    rotation about y moves the limb to the left: adduction on the right, abduction on the
    left. Positive flexion about z turns a segment forward. The distal frame: x forward
    along the foot or paw, y up (rest Rz(90) from the lower segment).
    """
    prox, mid, dist = (f"{side}_{n}" for n in names)
    lo, hi = ranges[f"{names[0]}_adduction"]
    add = (lo, hi) if side == "R" else (-hi, -lo)
    return [
        _joint(prox, "pelvis", offset,
               [_dof("z", f"{prox}_flexion", *ranges[f"{names[0]}_flexion"]),
                _dof("y", f"{prox}_adduction", *add),
                _dof("x", f"{prox}_rotation", *ranges[f"{names[0]}_rotation"])], rest=(0, 0, -90)),
        _joint(mid, prox, (upper, 0, 0), [_dof("z", f"{mid}_flexion", *ranges[f"{names[1]}_flexion"])]),
        _joint(dist, mid, (lower, 0, 0),
               [_dof("z", f"{dist}_dorsiflexion", *ranges[f"{names[2]}_dorsiflexion"])],
               rest=(0, 0, 90)),
    ]


def _pelvis() -> tuple[list[str], list[str]]:
    """The pelvis root (3 translations, 3 rotations) with RASI, LASI, SACR: (joints, markers)."""
    root = _pelvis_joint(THIGH + SHANK + ANKLE_HEIGHT, {
        "tx": (-1200, 1200), "ty": (-150, 100), "tz": (-400, 400), "rotation": (-40, 40),
        "obliquity": (-20, 20), "tilt": (-25, 25)})
    asis = (-HJC_FROM_ASIS[0], -HJC_FROM_ASIS[1], ASIS_WIDTH / 2)
    markers = [_marker("RASI", "pelvis", asis), _marker("LASI", "pelvis", (asis[0], asis[1], -asis[2])),
               _marker("SACR", "pelvis", (asis[0] - 160.0, asis[1], 0.0))]
    return [root], markers


def _leg(side: str) -> tuple[list[str], list[str]]:
    """One leg on the pelvis (hip 3 DOFs, knee, ankle) with its 6 markers: (joints, markers)."""
    s = 1.0 if side == "R" else -1.0
    joints = _leg_joints(side, HIP_HALF_WIDTH, THIGH, SHANK, {
        "hip_flexion": (-30, 120), "hip_adduction": (-45, 30), "hip_rotation": (-45, 45),
        "knee_flexion": (-140, 5), "ankle_dorsiflexion": (-50, 20)})
    markers = [
        _marker(f"{side}THI", f"{side}_hip", (0.65 * THIGH, 0, s * 75)),
        _marker(f"{side}KNE", f"{side}_knee", (0, 0, s * 50)),
        _marker(f"{side}TIB", f"{side}_knee", (0.65 * SHANK, 0, s * 50)),
        _marker(f"{side}ANK", f"{side}_ankle", (0, 0, s * 35)),
        _marker(f"{side}HEE", f"{side}_ankle", (-0.21 * FOOT, -0.5 * ANKLE_HEIGHT, 0)),
        _marker(f"{side}TOE", f"{side}_ankle", (0.55 * FOOT, -0.55 * ANKLE_HEIGHT, 0)),
    ]
    return joints, markers


def _lower_body() -> tuple[list[str], list[str]]:
    """The pelvis and both legs, right first: (joints, markers)."""
    joints, markers = _pelvis()
    for side in "RL":
        leg_joints, leg_markers = _leg(side)
        joints += leg_joints
        markers += leg_markers
    return joints, markers


def biped_xml() -> str:
    """A pelvis with 3 translations and 3 rotations; per leg hip 3, knee 1, ankle 1; 15 markers."""
    joints, markers = _lower_body()
    comment = """  <!-- A human lower body (height 1.75 m): pelvis root with 3 translations and 3 rotations,
       hip 3 DOFs, knee 1, ankle 1; Plug-in Gait markers (Davis et al. 1991) without the
       PSIS. Segments from Drillis & Contini 1966 (in Winter 2009, Fig. 4.1), hip joint
       centres from Bell et al. 1990, ranges from AAOS 1965 (Roaas & Andersson 1982).
       x forward (walking), y up, z right; mm. Made by bench/subjects/build.py;
       docs/BENCH_SUBJECTS.md. -->"""
    return "\n".join(['<model name="human_lower_body" units="mm">', comment, *joints, *markers,
                      "</model>", ""])


def biped_rig() -> dict:
    """Three cameras around a 2.4 m walkway, 5 m away and 1.8 m up, 720×576."""
    target = (0.0, 600.0, 0.0)
    return ring(["right", "left", "front"], [90, 270, 20], radius=5000.0, height=1800.0,
                target=target, f=1150.0, size=BIPED_SIZE, dist=(-0.08, 0.02, 0.0, 0.0, 0.0))


# ---- fullbody: a whole human, Plug-in Gait full-body markers -----------------------------------

# Heights above the floor, widths and lengths as fractions of body height (Drillis & Contini
# 1966, in Winter 2009, Fig. 4.1): shoulder 0.818, shoulder width 0.259, upper arm 0.186,
# forearm 0.146, hand 0.108. The hips are at 0.530 (thigh + shank + ankle height above).
SHOULDER_HEIGHT, SHOULDER_WIDTH = 0.818 * BODY_HEIGHT, 0.259 * BODY_HEIGHT
UPPER_ARM, FOREARM, HAND = 0.186 * BODY_HEIGHT, 0.146 * BODY_HEIGHT, 0.108 * BODY_HEIGHT
# The lumbar (back) joint from the hip joint centres' midpoint, the pelvis origin: OpenSim's
# gait models (Delp et al. 1990, IEEE Trans Biomed Eng 37:757-767) put the back joint at
# (-100.7, 81.5, 0) mm and the hips at (-70.7, -66.1, +-83.5) mm in their pelvis frame.
LUMBAR = (-100.7 + 70.7, 81.5 + 66.1, 0.0)
# The neck (C7/T1) and shoulder joints sit at shoulder height above the lumbar joint.
TRUNK = SHOULDER_HEIGHT - (THIGH + SHANK + ANKLE_HEIGHT) - LUMBAR[1]
# Joint ranges, AAOS 1965 (as tabulated by Norkin & White, Measurement of Joint Motion):
# thoracolumbar flexion 80, extension 25, lateral flexion 35, rotation 45; cervical flexion
# and extension 45, lateral flexion 45, rotation 60; shoulder flexion 180, extension 60,
# abduction 180, internal rotation 70, external 90; elbow flexion 150; pronation and
# supination 80; wrist flexion 80, extension 70. Shoulder adduction 30 is ours.
# Marker offsets (mm) on the thorax (frame at the lumbar joint) and head (at the neck joint).
THORAX_MARKERS = {"C7": (-50, TRUNK + 20, 0), "T10": (-80, 150, 0), "CLAV": (100, TRUNK - 15, 0),
                  "STRN": (150, 170, 0), "RBAK": (-90, 250, 90)}
HEAD_MARKERS = {"LFHD": (120, 215, -65), "RFHD": (120, 215, 65), "LBHD": (-50, 215, -55),
                "RBHD": (-50, 215, 55)}
FULLBODY_SIZE = (1280, 720)


def _arm(side: str) -> tuple[list[str], list[str]]:
    """One arm on the thorax: shoulder 3 DOFs, elbow flexion, forearm pronation, wrist flexion,
    with SHO (on the thorax), UPA, ELB, FRM, WRA, WRB, FIN: (joints, markers)."""
    s = 1.0 if side == "R" else -1.0
    # Local x down the arm, y forward, z to the right (rest Rz(-90)), as the legs; at zero the
    # thumb points forward. Positive about y moves the arm to the left and about x turns its
    # front to the right: adduction and external rotation on the right, the opposite on the left.
    add, rot = ((-180, 30), (-70, 90)) if side == "R" else ((-30, 180), (-90, 70))
    wrist = (-70, 80) if side == "R" else (-80, 70)  # about y: flexion on the right
    joints = [
        _joint(f"{side}_shoulder", "lumbar", (0, TRUNK, s * SHOULDER_WIDTH / 2),
               [_dof("z", f"{side}_shoulder_flexion", -60, 180),
                _dof("y", f"{side}_shoulder_adduction", *add),
                _dof("x", f"{side}_shoulder_rotation", *rot)], rest=(0, 0, -90)),
        _joint(f"{side}_elbow", f"{side}_shoulder", (UPPER_ARM, 0, 0),
               [_dof("z", f"{side}_elbow_flexion", 0, 150)]),
        # Pronation turns the forearm about its own axis: a joint of its own after the elbow.
        _joint(f"{side}_forearm", f"{side}_elbow", (0, 0, 0),
               [_dof("x", f"{side}_forearm_pronation", -80, 80)]),
        _joint(f"{side}_wrist", f"{side}_forearm", (FOREARM, 0, 0),
               [_dof("y", f"{side}_wrist_flexion", *wrist)]),
    ]
    markers = [
        _marker(f"{side}SHO", "lumbar", (0, TRUNK + 40, s * SHOULDER_WIDTH / 2)),
        _marker(f"{side}UPA", f"{side}_shoulder", (0.5 * UPPER_ARM, -20, s * 50)),
        _marker(f"{side}ELB", f"{side}_shoulder", (UPPER_ARM, 0, s * 45)),
        _marker(f"{side}FRM", f"{side}_forearm", (0.55 * FOREARM, -25, s * 30)),
        _marker(f"{side}WRA", f"{side}_forearm", (FOREARM, 35, 0)),
        _marker(f"{side}WRB", f"{side}_forearm", (FOREARM, -35, 0)),
        _marker(f"{side}FIN", f"{side}_wrist", (0.45 * HAND, 25, s * 20)),
    ]
    return joints, markers


def fullbody_xml() -> str:
    """The biped plus lumbar 3, neck 3 and per arm 6 DOFs (34); 38 Plug-in Gait markers."""
    joints, markers = _lower_body()
    joints += [
        _joint("lumbar", "pelvis", LUMBAR, [_dof("z", "lumbar_extension", -80, 25),
                                            _dof("x", "lumbar_bending", -35, 35),
                                            _dof("y", "lumbar_rotation", -45, 45)]),
        _joint("neck", "lumbar", (0, TRUNK, 0), [_dof("z", "neck_extension", -45, 45),
                                                 _dof("x", "neck_bending", -45, 45),
                                                 _dof("y", "neck_rotation", -60, 60)]),
    ]
    markers += [_marker(n, "lumbar", p) for n, p in THORAX_MARKERS.items()]
    markers += [_marker(n, "neck", p) for n, p in HEAD_MARKERS.items()]
    for side in "RL":
        arm_joints, arm_markers = _arm(side)
        joints += arm_joints
        markers += arm_markers
    comment = """  <!-- A whole human (height 1.75 m): the biped's pelvis and legs, a lumbar joint (extension,
       bending, rotation) carrying the thorax, a neck joint carrying the head, and per arm a
       3-DOF shoulder, elbow flexion, forearm pronation and wrist flexion (34 DOFs); Plug-in
       Gait full-body markers (Davis et al. 1991) without the PSIS. Segments from Drillis &
       Contini 1966 (in Winter 2009, Fig. 4.1), the lumbar joint from OpenSim's gait models,
       ranges from AAOS 1965. x forward (walking), y up, z right; mm. Made by
       bench/subjects/build.py; docs/BENCH_SUBJECTS.md. -->"""
    return "\n".join(['<model name="human_whole_body" units="mm">', comment, *joints, *markers,
                      "</model>", ""])


def fullbody_rig() -> dict:
    """Six cameras on a 6 m circle around the walkway, two of them 3 m up, 1280×720."""
    target = (0.0, 800.0, 0.0)
    return ring([f"cam{i}" for i in range(6)], [30, 90, 150, 210, 270, 330], radius=6000.0,
                height=[3000.0, 1400.0, 1400.0, 3000.0, 1400.0, 1400.0], target=target, f=1600.0,
                size=FULLBODY_SIZE, dist=(-0.06, 0.01, 0.0, 0.0, 0.0))


# ---- rat: a rat's hindquarters, rodent-lab skin markers ----------------------------------------

# Segment lengths (mm) of a ~300 g rat: the order of magnitude of Johnson et al. 2008 (J Biomech
# 41:610-619) and Hruska et al. 1979 as the brief gives it (femur ~35, tibia ~40, foot ~30), not
# read from those papers; the foot split into ankle-to-5th-metatarsal-head and on to the toe tip.
RAT_FEMUR, RAT_TIBIA, RAT_METATARSUS, RAT_TOE = 35.0, 40.0, 20.0, 12.0
# Ours: hip joint centres 20 mm apart; iliac crests 20 mm ahead of and 12 mm above the hips,
# 9 mm to each side; the tail base 15 mm behind and 8 mm above them. Markers sit 3-5 mm lateral
# of the bone (skin and fur).
RAT_HIP_HALF_WIDTH = 10.0
RAT_CREST, RAT_TAIL_BASE = (20.0, 12.0, 9.0), (-15.0, 8.0, 0.0)
RAT_HIP_HEIGHT = 72.0  # the pelvis origin at zero translation: the stance toes near y = 0
RAT_SIZE = (720, 576)


def _rat_pelvis() -> tuple[list[str], list[str]]:
    """The pelvis root (3 translations, 3 rotations) with both iliac crests and the tail base:
    (joints, markers)."""
    root = _pelvis_joint(RAT_HIP_HEIGHT, {
        "tx": (-120, 120), "ty": (-20, 20), "tz": (-40, 40), "rotation": (-30, 30),
        "obliquity": (-20, 20), "tilt": (-25, 25)})
    x, y, z = RAT_CREST
    markers = [_marker("R_crest", "pelvis", (x, y, z)), _marker("L_crest", "pelvis", (x, y, -z)),
               _marker("tail_base", "pelvis", RAT_TAIL_BASE)]
    return [root], markers


def _rat_leg(side: str) -> tuple[list[str], list[str]]:
    """One rat hindlimb: :func:`_rodent_hindlimb` with the rat's bones, markers 3-5 mm off the bone."""
    return _rodent_hindlimb(side, RAT_HIP_HALF_WIDTH, (RAT_FEMUR, RAT_TIBIA, RAT_METATARSUS, RAT_TOE),
                            skin=1.0, knee_flexion=150.0)


def _rodent_hindlimb(side: str, half_width: float, bones: tuple[float, float, float, float],
                     skin: float, knee_flexion: float) -> tuple[list[str], list[str]]:
    """One hindlimb on the pelvis (hip 3 DOFs, knee, ankle) with greater trochanter, knee
    (lateral condyle), ankle (lateral malleolus), 5th metatarsal head and toe tip:
    (joints, markers). ``bones``: femur, tibia, ankle to 5th metatarsal head, on to the toe
    tip; ``skin`` scales the markers' offsets from the bone (a rat's: 3-5 mm lateral, 2-3 mm
    below the foot); the knee flexes 0..``knee_flexion`` degrees. Frames and signs as the
    biped's legs (:func:`_leg_joints`)."""
    s = 1.0 if side == "R" else -1.0
    femur, tibia, metatarsus, toe = bones
    joints = _leg_joints(side, half_width, femur, tibia, {
        "hip_flexion": (-40, 110), "hip_adduction": (-40, 30), "hip_rotation": (-40, 40),
        "knee_flexion": (-knee_flexion, 0), "ankle_dorsiflexion": (-80, 60)})
    markers = [
        _marker(f"{side}_trochanter", f"{side}_hip", (-3 * skin, 0, s * 5 * skin)),
        _marker(f"{side}_knee", f"{side}_hip", (femur, 0, s * 4 * skin)),
        _marker(f"{side}_ankle", f"{side}_ankle", (0, 0, s * 3 * skin)),
        _marker(f"{side}_mt5", f"{side}_ankle", (metatarsus, -2 * skin, s * 4 * skin)),
        _marker(f"{side}_toe", f"{side}_ankle", (metatarsus + toe, -3 * skin, 0)),
    ]
    return joints, markers


def rat_xml() -> str:
    """A pelvis with 3 translations and 3 rotations; per leg hip 3, knee 1, ankle 1; 13 markers."""
    joints, markers = _rat_pelvis()
    for side in "RL":
        leg_joints, leg_markers = _rat_leg(side)
        joints += leg_joints
        markers += leg_markers
    comment = """  <!-- A rat's hindquarters (~300 g): pelvis root with 3 translations and 3 rotations, hip
       3 DOFs, knee 1, ankle 1 (16 DOFs); skin markers as rat gait studies place them: both
       iliac crests and the tail base, greater trochanter, knee, ankle, 5th metatarsal head,
       toe tip. Femur 35, tibia 40, foot 32 mm. x forward, y up, z right; mm.
       Made by bench/subjects/build.py; docs/BENCH_SUBJECTS.md. -->"""
    return "\n".join(['<model name="rat_hindquarters" units="mm">', comment, *joints, *markers,
                      "</model>", ""])


def rat_rig() -> dict:
    """Two lateral cameras 600 mm from the treadmill and one below its glass floor looking up
    from the front-right; 720×576, f = 840 px (1.4 px per mm at 600 mm)."""
    target, dist = (0.0, 35.0, 0.0), (-0.05, 0.01, 0.0, 0.0, 0.0)
    rig = ring(["right", "left"], [90, 270], radius=600.0, height=target[1] + 80.0,
               target=target, f=840.0, size=RAT_SIZE, dist=dist)
    below = look_at((250.0, -480.0, 200.0), target, f=840.0, size=RAT_SIZE, dist=dist)
    rig["views"].append({"name": "below", "video": 2, "projection": below})
    return rig


# ---- mouse: a whole mouse in a camera-and-mirror walkway -----------------------------------------

# Limb bones (mm) of an adult C57BL/6 mouse (~25 g), rounded to the order of magnitude that
# micro-CT studies of the strain report (femur ~15.5, tibia ~18, humerus ~12, ulna ~14), not
# read from one paper's table; hind foot split into ankle-to-5th-metatarsal-head and on to the
# toe tip, fore paw into wrist-to-5th-metacarpal-head and on to the digit tip.
MOUSE_FEMUR, MOUSE_TIBIA, MOUSE_METATARSUS, MOUSE_TOE = 15.5, 18.0, 8.0, 4.0
MOUSE_HUMERUS, MOUSE_ULNA, MOUSE_METACARPUS, MOUSE_DIGIT = 12.0, 14.0, 3.5, 3.0
# Ours: a rigid trunk (no spine or head DOFs) from the hips to the shoulders; hip joints 10 mm
# apart, shoulder joints 40 mm ahead of the hips, 6.5 mm lower (low on the chest, below a long
# upright scapula), 12 mm apart; iliac crests 5 mm ahead of and 4 mm above the hips, 5 mm to
# each side; the tail base 8 mm behind; the withers 38 mm ahead and 6 mm above. Markers sit
# 1.5-2.5 mm lateral of the bone.
MOUSE_HIP_HALF_WIDTH, MOUSE_SHOULDER = 5.0, (40.0, -6.5, 6.0)
MOUSE_CREST, MOUSE_TAIL_BASE, MOUSE_WITHERS = (5.0, 4.0, 5.0), (-8.0, 3.0, 0.0), (38.0, 6.0, 0.0)
MOUSE_HIP_HEIGHT = 34.0  # the pelvis origin at zero translation: the stance toes near y = 0
MOUSE_SIZE = (960, 512)
MOUSE_PX_PER_MM = 4.0


def _mouse_trunk() -> tuple[list[str], list[str]]:
    """The trunk root (3 translations, 3 rotations) with both iliac crests, the tail base and
    the withers: (joints, markers)."""
    root = _pelvis_joint(MOUSE_HIP_HEIGHT, {
        "tx": (-40, 40), "ty": (-6, 6), "tz": (-12, 12), "rotation": (-25, 25),
        "obliquity": (-15, 15), "tilt": (-20, 20)})
    x, y, z = MOUSE_CREST
    markers = [_marker("R_crest", "pelvis", (x, y, z)), _marker("L_crest", "pelvis", (x, y, -z)),
               _marker("tail_base", "pelvis", MOUSE_TAIL_BASE),
               _marker("withers", "pelvis", MOUSE_WITHERS)]
    return [root], markers


def _mouse_hindlimb(side: str) -> tuple[list[str], list[str]]:
    """One mouse hindlimb: :func:`_rodent_hindlimb` with the mouse's bones, markers 1.5-2.5 mm
    off the bone, the knee flexing to 170°."""
    return _rodent_hindlimb(side, MOUSE_HIP_HALF_WIDTH,
                            (MOUSE_FEMUR, MOUSE_TIBIA, MOUSE_METATARSUS, MOUSE_TOE), skin=0.5,
                            knee_flexion=170.0)


def _mouse_forelimb(side: str) -> tuple[list[str], list[str]]:
    """One forelimb (shoulder 3 DOFs, elbow, wrist) with greater tubercle, olecranon, wrist
    (ulnar styloid), 5th metacarpal head and digit tip: (joints, markers). The elbow flexes
    the other way from the knee: positive turns the forearm forward."""
    s = 1.0 if side == "R" else -1.0
    x, y, z = MOUSE_SHOULDER
    joints = _limb_joints(side, ("shoulder", "elbow", "wrist"), (x, y, s * z), MOUSE_HUMERUS,
                          MOUSE_ULNA, {
                              "shoulder_flexion": (-100, 40), "shoulder_adduction": (-30, 30),
                              "shoulder_rotation": (-40, 40), "elbow_flexion": (0, 150),
                              "wrist_dorsiflexion": (-90, 60)})
    markers = [
        _marker(f"{side}_shoulder", f"{side}_shoulder", (-1.5, 0, s * 2.5)),
        _marker(f"{side}_elbow", f"{side}_elbow", (0, -1.5, s * 2)),
        _marker(f"{side}_wrist", f"{side}_wrist", (0, 0, s * 1.5)),
        _marker(f"{side}_mc5", f"{side}_wrist", (MOUSE_METACARPUS, -0.5, s * 1.5)),
        _marker(f"{side}_digit", f"{side}_wrist", (MOUSE_METACARPUS + MOUSE_DIGIT, -1, 0)),
    ]
    return joints, markers


def mouse_xml() -> str:
    """A trunk with 3 translations and 3 rotations; per limb 3 + 1 + 1 DOFs; 24 markers."""
    joints, markers = _mouse_trunk()
    for limb in (_mouse_hindlimb, _mouse_forelimb):
        for side in "RL":
            limb_joints, limb_markers = limb(side)
            joints += limb_joints
            markers += limb_markers
    comment = """  <!-- A whole mouse (adult C57BL/6, ~25 g): a rigid trunk root with 3 translations and 3
       rotations carrying four limbs, hip or shoulder 3 DOFs, knee or elbow 1, ankle or wrist 1
       (26 DOFs); skin markers on both iliac crests, the tail base and the withers, and per
       limb at the greater trochanter or tubercle, knee or olecranon, ankle or wrist, 5th
       metatarsal or metacarpal head, and toe or digit tip. Femur 15.5, tibia 18, hind foot 12,
       humerus 12, ulna 14, fore paw 6.5 mm. x forward, y up, z right; mm.
       Made by bench/subjects/build.py; docs/BENCH_SUBJECTS.md. -->"""
    return "\n".join(['<model name="mouse" units="mm">', comment, *joints, *markers, "</model>", ""])


def mouse_rig() -> dict:
    """One camera filming a glass-floored walkway from the side and, through a 45° mirror
    below it, from underneath (LocoMouse's setup, Machado et al. 2015, eLife 4:e07892): two
    scaled orthographic views, 4 px per mm, in one 960×512 frame, the side view on top.
    The side view shows x right and y up; the bottom view x right and z down (the animal's
    right side lower in the frame)."""
    w, h = MOUSE_SIZE
    s = MOUSE_PX_PER_MM
    side = [[s, 0, 0, w / 2 - 15 * s], [0, -s, 0, h / 2 - 10 * s]]
    bottom = [[s, 0, 0, w / 2 - 15 * s], [0, 0, s, 3 * h / 4]]
    return {"views": [
        {"name": "side", "video": 0, "roi": [0, 0, w, h // 2],
         "projection": {"type": "affine", "matrix": side}},
        {"name": "bottom", "video": 0, "roi": [0, h // 2, w, h // 2],
         "projection": {"type": "affine", "matrix": bottom}}]}


# ---- spider: a wolf spider (Lycosidae) --------------------------------------------------------

# A large female lycosid (Lycosa/Hogna, carapace about 10 mm). Leg segment lengths: the
# proportions of taxonomic descriptions of large Lycosidae (leg formula IV > I > II > III),
# rounded, not read from one paper's table; coxa and trochanter lengths ours. Frame: x
# forward, y up, z right; mm.
# coxa, trochanter, femur, patella, tibia, metatarsus, tarsus (mm), per leg pair 1..4
SPIDER_SEGMENTS = {
    "1": (3.2, 1.4, 8.0, 4.0, 6.6, 6.4, 3.6),
    "2": (3.0, 1.3, 7.6, 3.8, 6.0, 6.2, 3.4),
    "3": (2.8, 1.2, 7.0, 3.2, 5.2, 6.6, 3.2),
    "4": (3.0, 1.3, 9.0, 3.6, 7.6, 10.4, 4.2),
}
# Coxa insertions around the sternum (x, y, z of the right leg; left mirrors z) and the
# resting azimuth of each leg (degrees ahead of lateral).
SPIDER_INSERTION = {"1": (2.6, 0.0, 2.4), "2": (1.0, 0.0, 3.1), "3": (-0.8, 0.0, 3.1),
                    "4": (-2.4, 0.0, 2.4)}
SPIDER_AZIMUTH = {"1": 45.0, "2": 15.0, "3": -15.0, "4": -45.0}
# Ranges (degrees). coxa_yaw: promotion (+) / remotion about the resting azimuth;
# coxa_pitch: levation (+) at the body-coxa joint; femur_pitch: coxa-trochanter and
# trochanter-femur levation lumped; patella_pitch: femur-patella flexion (-);
# tibia_yaw: patella-tibia lateral rotation; metatarsus_pitch: tibia-metatarsus flexion (-).
# Ours, widened around reported walking excursions (body-coxa ~±30, femur-patella
# ~60-80 deg of excursion, tibia-metatarsus ~40 in Cupiennius/Lycosa walking).
SPIDER_RANGES = {
    "coxa_yaw": (-45.0, 45.0), "coxa_pitch": (-25.0, 35.0), "femur_pitch": (-10.0, 80.0),
    "patella_pitch": (-120.0, 10.0), "tibia_yaw": (-30.0, 30.0), "metatarsus_pitch": (-100.0, 15.0),
}
TARSUS_BEND = -15.0  # fixed bend of the tarsus against the metatarsus (rest about z)
# Cephalothorax markers (on the carapace) and the pedicel/abdomen.
CEPH_MARKERS = {"eyes": (4.6, 2.6, 0.0), "fovea": (-1.2, 3.0, 0.0), "ceph_R": (0.8, 2.2, 3.0),
                "ceph_L": (0.8, 2.2, -3.0)}
PEDICEL = (-5.2, 1.0, 0.0)
ABDOMEN_MARKERS = {"abd_mid": (5.5, 3.0, 0.0), "abd_tip": (11.5, 0.8, 0.0)}  # x backward
CEPH_RANGES = (("tx", "ceph_tx", -30, 30), ("ty", "ceph_ty", -4, 4), ("tz", "ceph_tz", -20, 20),
               ("y", "ceph_yaw", -60, 60), ("x", "ceph_roll", -15, 15), ("z", "ceph_pitch", -15, 15))
CEPH_HEIGHT = 6.0  # the carapace root above the floor at zero translation (mm)
# 4 cameras: two 1280x1024 (machine vision), two 640x480 (one with a wide lens).
SPIDER_SIZES = ((1280, 1024), (640, 480), (1280, 1024), (640, 480))


def spider_xml() -> str:
    joints = [_joint("ceph", None, (0, CEPH_HEIGHT, 0),
                     [_dof(a, n, lo, hi) for a, n, lo, hi in CEPH_RANGES])]
    markers = [_marker(n, "ceph", p) for n, p in CEPH_MARKERS.items()]
    joints.append(_joint("abdomen", "ceph", PEDICEL,
                         [_dof("y", "abd_yaw", -25, 25), _dof("z", "abd_pitch", -30, 30)],
                         rest=(180.0, 0.0, 0.0)))
    markers += [_marker(n, "abdomen", p) for n, p in ABDOMEN_MARKERS.items()]
    for side in "RL":
        s = 1.0 if side == "R" else -1.0
        for pair in "1234":
            leg = f"{side}{pair}"
            cx, tr, fe, pa, ti, mt, ta = SPIDER_SEGMENTS[pair]
            x, y, z = SPIDER_INSERTION[pair]
            # Right legs: Ry(-(90 - az)) points local x laterally, az ahead of lateral; a positive
            # rotation about y turns a right leg forward, a left one backward: promotion is
            # +yaw on the right, -yaw on the left (ranges are symmetric).
            rest_y = -(90.0 - SPIDER_AZIMUTH[pair]) * s
            R = SPIDER_RANGES
            joints += [
                _joint(f"{leg}_coxa", "ceph", (x, y, s * z),
                       [_dof("y", f"{leg}_coxa_yaw", *R["coxa_yaw"]),
                        _dof("z", f"{leg}_coxa_pitch", *R["coxa_pitch"])], rest=(rest_y, 0, 0)),
                _joint(f"{leg}_femur", f"{leg}_coxa", (cx + tr, 0, 0),
                       [_dof("z", f"{leg}_femur_pitch", *R["femur_pitch"])]),
                _joint(f"{leg}_patella", f"{leg}_femur", (fe, 0, 0),
                       [_dof("z", f"{leg}_patella_pitch", *R["patella_pitch"])]),
                _joint(f"{leg}_tibia", f"{leg}_patella", (pa, 0, 0),
                       [_dof("y", f"{leg}_tibia_yaw", *R["tibia_yaw"])]),
                _joint(f"{leg}_metatarsus", f"{leg}_tibia", (ti, 0, 0),
                       [_dof("z", f"{leg}_metatarsus_pitch", *R["metatarsus_pitch"])]),
                _joint(f"{leg}_tarsus", f"{leg}_metatarsus", (mt, 0, 0), [],
                       rest=(0.0, 0.0, TARSUS_BEND)),
                _joint(f"{leg}_claw", f"{leg}_tarsus", (ta, 0, 0), []),
            ]
            # coxa-trochanter joint, femur-patella joint, tibia-metatarsus joint, claw
            markers += [_marker(f"{leg}_CTr", f"{leg}_coxa", (cx, 0, 0)),
                        _marker(f"{leg}_FPa", f"{leg}_patella"),
                        _marker(f"{leg}_TiMt", f"{leg}_metatarsus"),
                        _marker(f"{leg}_claw", f"{leg}_claw")]
    comment = """  <!-- A wolf spider (Lycosidae, large female, carapace ~10 mm): cephalothorax root free
       (3 translations, yaw, roll, pitch) with 4 carapace markers; abdomen on a 2-DOF pedicel
       (yaw, pitch) with 2 markers; 8 legs of 6 DOFs (coxa yaw and pitch, femur pitch, patella
       pitch, tibia yaw, metatarsus pitch), tarsus rigid; markers at coxa-trochanter,
       femur-patella, tibia-metatarsus and the claw.
       x forward, y up, z right; mm. -->"""
    return "\n".join(['<model name="wolf_spider" units="mm">', comment, *joints, *markers,
                      "</model>", ""])


def spider_rig() -> dict:
    """Four cameras around and above an arena, ~60-120 mm away."""
    target = (0.0, 2.0, 0.0)
    specs = [  # name, azimuth (deg from +x toward +z), radius, height, f, distortion
        ("hs_front_right", 40.0, 150.0, 110.0, 2000.0, (-0.04, 0.0, 0.0, 0.0, 0.0)),
        ("wide_back_right", 150.0, 110.0, 90.0, 620.0, (-0.18, 0.05, 0.0005, -0.0005, 0.0)),
        ("hs_back_left", 220.0, 150.0, 120.0, 2000.0, (-0.03, 0.0, 0.0, 0.0, 0.0)),
        ("top_left", 300.0, 40.0, 160.0, 720.0, (0.0, 0.0, 0.0, 0.0, 0.0)),
    ]
    views = []
    for i, (name, az, r, h, f, dist) in enumerate(specs):
        a = np.radians(az)
        pos = (target[0] + r * np.cos(a), h, target[2] + r * np.sin(a))
        views.append({"name": name, "video": i,
                      "projection": look_at(pos, target, f=f, size=SPIDER_SIZES[i], dist=dist)})
    return {"views": views}


def main() -> None:
    for name, xml, rig in (("hexapod", hexapod_xml(), hexapod_rig()),
                           ("biped", biped_xml(), biped_rig()),
                           ("fullbody", fullbody_xml(), fullbody_rig()),
                           ("rat", rat_xml(), rat_rig()),
                           ("mouse", mouse_xml(), mouse_rig()),
                           ("freefly", hexapod_xml(free=True), hexapod_rig()),
                           ("spider", spider_xml(), spider_rig())):
        folder = HERE / name
        folder.mkdir(exist_ok=True)
        (folder / "model.xml").write_text(xml)
        (folder / "rig.json").write_text(json.dumps(rig, indent=1) + "\n")


if __name__ == "__main__":
    main()
