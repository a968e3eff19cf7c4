"""Benchmark subjects: model, rig and natural movements of whole animals (``bench/animals.py``).

Each subject is a model (FORMATS §1) and a rig (FORMATS §2) in ``bench/subjects/<name>/``
or ``core/examples/<name>/``, a frame size (per video where they differ), a frame rate, and a
movement generator:

- ``hexapod``: a tethered fruit fly, 6 legs × 7 DOFs, walking in a tripod gait;
- ``freefly``: the same fly with its thorax free (3 translations, 3 rotations), turning,
  pitching, rolling and shifting as it walks;
- ``biped``: a human lower body walking along a 2.4 m walkway, pelvis moving forward;
- ``fullbody``: a whole human (spine, head, arms) walking there, swinging its arms;
- ``rat``: a rat's hindquarters trotting on a treadmill, filmed from both sides and below;
- ``mouse``: a whole mouse trotting along a walkway, one camera filming it from the side and
  through a mirror from below;
- ``spider``: a wolf spider, its cephalothorax free, 8 legs × 6 DOFs, walking in an
  alternating tetrapod gait, filmed by four cameras of two frame sizes;
- ``stick`` and ``locust``: the examples, moved by ``core.synth.natural_movements``.

Sources of the anatomy: ``docs/BENCH_SUBJECTS.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from core.examples import EXAMPLES
from core.model import KinematicModel, Marker
from core.rig import Rig
from core.synth import natural_movements

ROOT = Path(__file__).resolve().parents[2]
NAMES = ("hexapod", "freefly", "biped", "fullbody", "stick", "locust", "rat", "mouse", "spider")
# Camera subsets of the hexapod's six (a ring at 30, 90, …, 330° azimuth): every other one,
# and the two side cameras.
HEXAPOD_CAMERAS = {6: (0, 1, 2, 3, 4, 5), 3: (0, 2, 4), 2: (1, 4)}
# The rat's three (right, left, below) and its two side cameras.
RAT_CAMERAS = {3: (0, 1, 2), 2: (0, 1)}
# The spider's four (two 1280x1024 high-speed, a wide 640x480, a 640x480 from above) and the
# two high-speed cameras on opposite sides.
SPIDER_CAMERAS = {4: (0, 1, 2, 3), 2: (0, 2)}
SPIDER_SIZES = ((1280, 1024), (640, 480), (1280, 1024), (640, 480))
CAMERAS = {"hexapod": HEXAPOD_CAMERAS, "freefly": HEXAPOD_CAMERAS, "rat": RAT_CAMERAS,
           "spider": SPIDER_CAMERAS}


@dataclass(frozen=True)
class Subject:
    """A benchmark subject.

    unmodelled : (joint, position in its frame) of each marker the model lacks, drawn in
        every view with soft tissue (real markers the lab did not model).
    """

    name: str
    model: KinematicModel
    rig: Rig
    frame_sizes: tuple[tuple[int, int], ...]  # (width, height) of each video file, in index order
    fps: float
    movement: Callable[[Subject, int, np.random.Generator], np.ndarray]
    unmodelled: tuple[tuple[str, tuple[float, float, float]], ...]

    def __post_init__(self) -> None:
        """The rig filming ``frame_sizes`` (``core.rig.Rig.framed``), as a job's videos give it."""
        object.__setattr__(self, "rig", self.rig.framed(self.frame_sizes))

    def size_of(self, video: int) -> tuple[int, int]:
        """The frame size of video ``video``."""
        return self.frame_sizes[video]

    def trajectory(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, D) true postures, model-file DOF order (degrees, model units)."""
        return self.movement(self, n, rng)

    def with_unmodelled_markers(self) -> KinematicModel:
        """The model plus the unmodelled markers (last, in order), for rendering only."""
        extra = tuple(Marker("unmodelled" + (str(i + 1) if i else ""), joint, pos)
                      for i, (joint, pos) in enumerate(self.unmodelled))
        return replace(self.model, markers=(*self.model.markers, *extra))


def load(name: str, cameras: int | None = None) -> Subject:
    """The subject ``name`` (one of :data:`NAMES`); ``cameras`` picks a subset of its views
    (:data:`CAMERAS`: the flies' 6, 3 or 2, the rat's 3 or 2, the spider's 4 or 2; all by
    default)."""
    if name not in NAMES:
        raise ValueError(f"subject must be one of {', '.join(NAMES)}, got {name!r}")
    folder = {"stick": EXAMPLES / "stick_insect_front_leg",
              "locust": EXAMPLES / "locust_hind_leg"}.get(name, ROOT / "bench" / "subjects" / name)
    model = KinematicModel.from_xml(folder / "model.xml")
    rig = Rig.from_json(folder / "rig.json")
    if cameras is not None:
        if cameras not in CAMERAS.get(name, {}):
            raise ValueError(f"{name!r} has no {cameras}-camera variant")
        # Each camera keeps its own video file: renumber the chosen ones 0..k-1.
        rig = Rig(tuple(replace(rig.views[v], video=i) for i, v in enumerate(CAMERAS[name][cameras])))
    if name == "spider":  # unmodelled: a marker on the right leg 4 femur, mid-shaft
        sizes = tuple(SPIDER_SIZES[v] for v in SPIDER_CAMERAS[4 if cameras is None else cameras])
        return Subject(name, model, rig, sizes, 100.0, spider_walk, (("R4_femur", (4.5, 0.4, 0.0)),))
    every = {"hexapod": (640, 480), "freefly": (640, 480), "fullbody": (1280, 720),
             "mouse": (960, 512)}.get(name, (720, 576))
    sizes = (every,) * rig.n_videos
    if name in ("hexapod", "freefly"):
        return Subject(name, model, rig, sizes, 100.0,
                       tripod_walk if name == "hexapod" else free_walk,
                       (("RM_femur_roll", (0.45, 0.03, 0.0)),))
    if name == "biped":
        return Subject(name, model, rig, sizes, 100.0, walkway_gait,
                       (("R_knee", (200.0, 60.0, 0.0)),))
    if name == "fullbody":  # the unmodelled marker: on the back of the right upper arm
        return Subject(name, model, rig, sizes, 100.0, fullbody_gait,
                       (("R_shoulder", (120.0, -45.0, 30.0)),))
    if name == "rat":  # unmodelled: a lumbar spine marker and one on the right mid-thigh
        return Subject(name, model, rig, sizes, 200.0, treadmill_trot,
                       (("pelvis", (40.0, 14.0, 0.0)), ("R_hip", (17.5, 0.0, 5.0))))
    if name == "mouse":  # unmodelled: a mid-back marker and one on the left mid-forearm
        return Subject(name, model, rig, sizes, 250.0, walkway_trot,
                       (("pelvis", (20.0, 7.0, 0.0)), ("L_elbow", (7.0, 0.0, -2.0))))
    unmodelled = ("femur_tibia", (12.0, 1.0, 0.0)) if name == "stick" else ("femur_tibia", (14.0, 1.5, 0.0))
    return Subject(name, model, rig, sizes, 50.0, _natural, (unmodelled,))


def camera_choice(name: str, asked: int | None) -> int | None:
    """The ``cameras`` to :func:`load` subject ``name`` with when a run asks for ``asked``
    (None: the default): ``asked`` if the subject has that variant, else the hexapod's 6
    (named in its labels; the free fly's too) and every other subject's full rig (None)."""
    if asked in CAMERAS.get(name, {}):
        return asked
    return 6 if name in ("hexapod", "freefly") else None


def _natural(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    return natural_movements(subject.model, subject.rig, n, rng=rng, fps=subject.fps,
                             frame_size=subject.size_of(0))


# ---- hexapod: tripod walking ---------------------------------------------------------------------

# Per leg pair: centre and amplitude (degrees) of each DOF's oscillation, in the order coxa pro,
# roll, abd, femur, femur roll, tibia, tarsus (protraction and adduction positive), and each
# DOF's phase lead (radians) over protraction. Tethered flies walk at 5-15 steps/s.
_FLY_CENTRE = {"F": (25, 0, -10, -105, 0, 90, -40), "M": (0, 0, -12, -105, 0, 105, -45),
               "H": (-25, 0, -12, -105, 0, 100, -40)}
_FLY_AMPLITUDE = {"F": (20, 8, 6, 12, 8, 25, 12), "M": (20, 8, 6, 12, 8, 20, 12),
                  "H": (18, 8, 6, 12, 8, 20, 12)}
_FLY_PHASE = (0.0, np.pi / 2, np.pi / 3, np.pi / 2, -np.pi / 3, np.pi / 2 + 0.3, np.pi)
_TRIPOD = {"LF": 0.0, "RM": 0.0, "LH": 0.0, "RF": 0.5, "LM": 0.5, "RH": 0.5}
_STEP_HZ = (6.0, 11.0)


def tripod_walk(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """A tripod gait: each DOF a sinusoid of the step phase, with slowly drifting step rate,
    amplitude and centre (turning, speeding up), the two tripods half a cycle apart.

    Returns (n, D) postures in model order, inside the DOF ranges: the 42 leg DOFs, any
    others (a free thorax's) zero.
    """
    t = np.arange(n) / subject.fps
    rate = _smooth_noise(rng, t, 0.5, *_STEP_HZ)
    phase = 2 * np.pi * np.cumsum(rate) / subject.fps + rng.uniform(0, 2 * np.pi)
    names = subject.model.dof_names
    q = np.zeros((n, len(names)))  # a free thorax's columns: free_walk's
    for leg, offset in _TRIPOD.items():
        pair, mirror = leg[1], -1.0 if leg[0] == "R" else 1.0
        for k, dof in enumerate(("coxa_pro", "coxa_roll", "coxa_abd", "femur", "femur_roll",
                                 "tibia", "tarsus")):
            gain = _smooth_noise(rng, t, 1.0, 0.7, 1.15)
            drift = _smooth_noise(rng, t, 1.0, -0.4, 0.4) * _FLY_AMPLITUDE[pair][k]
            value = _FLY_CENTRE[pair][k] + drift + gain * _FLY_AMPLITUDE[pair][k] * np.cos(
                phase + 2 * np.pi * offset + _FLY_PHASE[k])
            # Protraction and the rolls turn the other way on the right (mirrored frames).
            sign = mirror if dof in ("coxa_pro", "coxa_roll", "femur_roll") else 1.0
            q[:, names.index(f"{leg}_{dof}")] = sign * value
    return _inside(subject.model, q)


# The free fly's thorax sway: per DOF, the half-range (mm, degrees) of a smooth random
# signal varying over about 0.7 s, inside the model's ranges (bench/subjects/build.py).
_THORAX_SWAY = {"thorax_tx": 0.3, "thorax_ty": 0.12, "thorax_tz": 0.2, "thorax_yaw": 20.0,
                "thorax_roll": 7.0, "thorax_pitch": 8.0}


def free_walk(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """:func:`tripod_walk`'s legs (the same as the tethered fly's for the same ``rng``) on a
    thorax that turns, pitches, rolls and shifts (:data:`_THORAX_SWAY`), kept within the
    cameras' view (a fly walking off would leave it).

    Returns (n, 48) postures in model order, inside the DOF ranges.
    """
    q = tripod_walk(subject, n, rng)
    t = np.arange(n) / subject.fps
    names = subject.model.dof_names
    for name, half in _THORAX_SWAY.items():
        q[:, names.index(name)] = _smooth_noise(rng, t, 0.7, -half, half)
    return _inside(subject.model, q)


# ---- biped: walking along the walkway ------------------------------------------------------------

# Sagittal joint angles over a gait cycle (% of the cycle from heel strike: degrees), the
# shape of the normative curves of Winter 2009 (Biomechanics and Motor Control of Human
# Movement, ch. 4) read to a few degrees: hip flexion, knee flexion, ankle dorsiflexion.
_HIP = ((0, 30), (10, 28), (30, 10), (50, -10), (60, -5), (70, 15), (85, 32), (100, 30))
_KNEE = ((0, 5), (15, 18), (40, 3), (60, 38), (73, 62), (90, 20), (100, 5))
_ANKLE = ((0, 0), (8, -6), (45, 10), (62, -18), (75, -5), (100, 0))
_WALKWAY = 1600.0  # mm of travel per pass, centred on the origin
_SPEED = (1100.0, 1500.0)  # mm/s
_STRIDE_S = (1.0, 1.2)


def walkway_gait(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """Passes along the walkway (x), each from one end to the other at its own speed,
    cadence and heading, the pelvis moving forward; the left leg half a cycle behind the right.

    Returns (n, 16) postures in model order, inside the DOF ranges.
    """
    cols, _ = _gait(n, subject.fps, rng)
    return _inside(subject.model, _in_model_order(subject.model, cols))


def _gait(n: int, fps: float, rng: np.random.Generator) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The pelvis's and legs' columns of :func:`walkway_gait` ((n,) each, by DOF name) and
    the right leg's gait phase ((n,), 0..1 from heel strike)."""
    cols: dict[str, np.ndarray] = {}
    phase = np.empty(n)
    start = 0
    while start < n:
        speed, stride = rng.uniform(*_SPEED), rng.uniform(*_STRIDE_S)
        length = min(n - start, int(_WALKWAY / speed * fps))
        t = np.arange(length) / fps
        p = (t / stride + rng.uniform()) % 1.0  # right leg's phase
        heading = np.radians(rng.uniform(-8, 8))
        gain = rng.uniform(0.85, 1.1)
        s = speed * t - _WALKWAY / 2
        lateral = rng.uniform(-150, 150)
        part = {
            "pelvis_tx": s * np.cos(heading),
            "pelvis_tz": lateral + s * np.sin(heading),
            "pelvis_ty": -25 + 15 * np.cos(4 * np.pi * p),
            "pelvis_rotation": -np.degrees(heading) + 4 * np.cos(2 * np.pi * p),
            "pelvis_obliquity": 4 * np.cos(2 * np.pi * (p - 0.15)),
            "pelvis_tilt": -2 + 2 * np.cos(4 * np.pi * p),
        }
        for side, ps, mirror in (("R", p, 1.0), ("L", (p + 0.5) % 1.0, -1.0)):
            part[f"{side}_hip_flexion"] = gain * _cycle(_HIP, ps)
            part[f"{side}_knee_flexion"] = -gain * _cycle(_KNEE, ps)
            part[f"{side}_ankle_dorsiflexion"] = gain * _cycle(_ANKLE, ps)
            part[f"{side}_hip_adduction"] = mirror * (2 + 4 * np.cos(2 * np.pi * (ps - 0.15)))
            part[f"{side}_hip_rotation"] = mirror * 5 * np.cos(2 * np.pi * (ps - 0.3))
        for name, values in part.items():
            cols.setdefault(name, np.empty(n))[start : start + length] = values
        phase[start : start + length] = p
        start += length
    return cols, phase


# ---- fullbody: walking with arm swing ------------------------------------------------------------


def fullbody_gait(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """:func:`walkway_gait` for the pelvis and legs, plus arm swing (each shoulder's flexion
    out of phase with the same side's hip, the elbow more flexed as the arm swings forward),
    the thorax turning against the pelvis, and the head nodding and looking about; every
    amplitude and centre drifts over a few seconds.

    Returns (n, 34) postures in model order, inside the DOF ranges.
    """
    cols, p = _gait(n, subject.fps, rng)
    t = np.arange(n) / subject.fps

    def drift(lo: float, hi: float, period_s: float = 2.0) -> np.ndarray:
        return _smooth_noise(rng, t, period_s, lo, hi)

    swing = 2 * np.pi * p
    cols["lumbar_extension"] = drift(-6, 0) + 2 * np.cos(2 * swing)
    cols["lumbar_bending"] = -drift(2, 4) * np.cos(swing - 0.3 * np.pi)  # against the pelvis's list
    cols["lumbar_rotation"] = -drift(6, 9) * np.cos(swing)  # the thorax turns against the pelvis
    cols["neck_extension"] = drift(-5, 5) + 1.5 * np.cos(2 * swing)
    cols["neck_bending"] = drift(-3, 3)
    cols["neck_rotation"] = drift(-8, 8, 3.0) - 0.5 * cols["lumbar_rotation"]
    for side, ps, mirror in (("R", swing, 1.0), ("L", swing + np.pi, -1.0)):
        forward = -np.cos(ps)  # the arm is back when the same side's hip is forward
        cols[f"{side}_shoulder_flexion"] = drift(0, 6) + drift(20, 30) * forward
        cols[f"{side}_elbow_flexion"] = 30 + drift(12, 15) * forward
        cols[f"{side}_shoulder_adduction"] = mirror * (drift(-10, -5) + 2 * np.cos(2 * ps))
        cols[f"{side}_shoulder_rotation"] = mirror * (drift(-8, 0) + 3 * forward)
        cols[f"{side}_forearm_pronation"] = mirror * drift(-15, 15)
        cols[f"{side}_wrist_flexion"] = mirror * (drift(-5, 10) + 4 * forward)
    return _inside(subject.model, _in_model_order(subject.model, cols))


# ---- rat: trotting on a treadmill ----------------------------------------------------------------

# Sagittal angles over a stride (% of the cycle from touchdown: degrees) in the model's terms:
# hip flexion (the femur forward of vertical), knee flexion (positive here, negated into the
# model) and ankle dorsiflexion (0: foot perpendicular to the tibia). Stance ends at about 60 %.
# Shapes of rat treadmill kinematics as described in docs/BENCH_SUBJECTS.md §6 (ours, not read
# from a figure): the hip extends through stance, the knee yields then extends, the ankle
# dorsiflexes in stance and plantarflexes sharply at push-off.
_RAT_HIP = ((0, 55), (30, 32), (60, 5), (75, 25), (90, 55), (100, 55))
_RAT_KNEE = ((0, 60), (15, 78), (50, 50), (62, 55), (75, 100), (85, 105), (95, 70), (100, 60))
_RAT_ANKLE = ((0, 0), (15, 28), (35, 38), (50, 33), (62, -20), (75, 20), (85, 35), (95, 10), (100, 0))
_RAT_STRIDE_HZ = (3.0, 4.0)


def treadmill_trot(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """A rat trotting on a treadmill: the stride rate drifting within 3-4 Hz, the left hindlimb
    half a cycle behind the right, each leg's amplitude drifting (×0.85-1.1); the pelvis
    wandering over the belt (±40 mm along, ±10 across over ~2 s), bobbing ±2.5 mm twice per
    stride, rolling ±4° and yawing ±3° per stride about a drifting heading (±6°), pitching ±3°
    twice per stride about a drifting ±4°.

    Returns (n, 16) postures in model order, inside the DOF ranges.
    """
    p, drift = _stride_clock(subject.fps, n, _RAT_STRIDE_HZ, rng)
    cols = _trotting_pelvis(p, drift, along=40.0, across=10.0, height=-5.0, bob=2.5)
    _hindlimbs(cols, p, drift)
    return _inside(subject.model, _in_model_order(subject.model, cols))


# ---- mouse: trotting along a walkway ---------------------------------------------------------------

# Forelimb angles over a stride (% of the cycle from touchdown: degrees) in the model's terms:
# shoulder flexion (the humerus forward of vertical; a mouse's points back and down), elbow
# flexion (positive turns the forearm forward) and wrist dorsiflexion (0: paw perpendicular
# to the forearm). Ours, shaped as rodent forelimb kinematics are described (the humerus
# retracts through stance, the elbow extends at push-off and flexes in swing, the paw stays
# flat in stance and curls in swing); stance ends at about 60 %.
_MOUSE_SHOULDER = ((0, -50), (30, -63), (60, -77), (75, -70), (90, -53), (100, -50))
_MOUSE_ELBOW = ((0, 75), (30, 80), (60, 60), (75, 105), (90, 100), (100, 75))
_MOUSE_WRIST = ((0, -20), (30, 0), (55, 25), (65, -40), (80, -50), (92, -25), (100, -20))
_MOUSE_STRIDE_HZ = (3.5, 5.0)


def walkway_trot(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """A mouse trotting along the walkway: the rat's hindlimbs (:func:`treadmill_trot`),
    crouched (hips 30° more flexed, knees 40° more), and forelimbs in diagonal pairs (left
    fore with right hind), the stride rate drifting within 3.5-5 Hz; the trunk wandering
    ±20 mm along and ±4 mm across, bobbing ±1 mm, rolling, yawing and pitching as the rat's
    pelvis.

    Returns (n, 26) postures in model order, inside the DOF ranges.
    """
    p, drift = _stride_clock(subject.fps, n, _MOUSE_STRIDE_HZ, rng)
    cols = _trotting_pelvis(p, drift, along=20.0, across=4.0, height=-1.0, bob=1.0)
    _hindlimbs(cols, p, drift, crouch=(30.0, -40.0))
    for side, ps, mirror in (("L", p, -1.0), ("R", (p + 0.5) % 1.0, 1.0)):
        gain = drift(0.85, 1.1, 1.0)
        cols[f"{side}_shoulder_flexion"] = gain * _cycle(_MOUSE_SHOULDER, ps)
        cols[f"{side}_elbow_flexion"] = gain * _cycle(_MOUSE_ELBOW, ps)
        cols[f"{side}_wrist_dorsiflexion"] = gain * _cycle(_MOUSE_WRIST, ps)
        cols[f"{side}_shoulder_adduction"] = mirror * (drift(-3, 3) + 3 * np.cos(2 * np.pi * (ps - 0.2)))
        cols[f"{side}_shoulder_rotation"] = mirror * (drift(-5, 5) + 4 * np.cos(2 * np.pi * (ps - 0.3)))
    return _inside(subject.model, _in_model_order(subject.model, cols))


def _stride_clock(fps: float, n: int, stride_hz: tuple[float, float], rng: np.random.Generator
                  ) -> tuple[np.ndarray, Callable[..., np.ndarray]]:
    """The right hindlimb's stride phase ((n,), 0..1 from touchdown, the rate drifting within
    ``stride_hz`` over ~1 s) and ``drift(lo, hi, period_s=2.0)``, a smooth random (n,) signal."""
    t = np.arange(n) / fps
    rate = _smooth_noise(rng, t, 1.0, *stride_hz)
    p = (np.cumsum(rate) / fps + rng.uniform()) % 1.0

    def drift(lo: float, hi: float, period_s: float = 2.0) -> np.ndarray:
        return _smooth_noise(rng, t, period_s, lo, hi)

    return p, drift


def _trotting_pelvis(p: np.ndarray, drift: Callable[..., np.ndarray], *, along: float,
                     across: float, height: float, bob: float) -> dict[str, np.ndarray]:
    """The pelvis's columns of a trot at phase ``p``: wandering ±``along`` and ±``across`` mm
    over ~2 s, ``height`` ± ``bob`` mm twice per stride, rolling ±4°, yawing ±3° per stride
    about a drifting ±6°, pitching ±3° twice per stride about a drifting ±4°."""
    swing = 2 * np.pi * p
    return {
        "pelvis_tx": drift(-along, along),
        "pelvis_tz": drift(-across, across),
        "pelvis_ty": height + bob * np.cos(2 * swing),
        "pelvis_rotation": drift(-6, 6) + 3 * np.cos(swing),
        "pelvis_obliquity": 4 * np.cos(swing - 0.3 * np.pi),
        "pelvis_tilt": drift(-4, 4) + 3 * np.cos(2 * swing),
    }


def _hindlimbs(cols: dict[str, np.ndarray], p: np.ndarray, drift: Callable[..., np.ndarray],
               crouch: tuple[float, float] = (0.0, 0.0)) -> None:
    """Add the rat's trotting hindlimbs at phase ``p`` (the left half a cycle behind) to
    ``cols``, each limb's amplitude drifting ×0.85-1.1, ``crouch`` (degrees) added to every
    hip's and knee's flexion."""
    for side, ps, mirror in (("R", p, 1.0), ("L", (p + 0.5) % 1.0, -1.0)):
        gain = drift(0.85, 1.1, 1.0)
        cols[f"{side}_hip_flexion"] = crouch[0] + gain * _cycle(_RAT_HIP, ps)
        cols[f"{side}_knee_flexion"] = crouch[1] - gain * _cycle(_RAT_KNEE, ps)
        cols[f"{side}_ankle_dorsiflexion"] = gain * _cycle(_RAT_ANKLE, ps)
        cols[f"{side}_hip_adduction"] = mirror * (drift(-3, 3) + 3 * np.cos(2 * np.pi * (ps - 0.15)))
        cols[f"{side}_hip_rotation"] = mirror * (drift(-5, 5) + 5 * np.cos(2 * np.pi * (ps - 0.3)))


def _in_model_order(model: KinematicModel, cols: dict[str, np.ndarray]) -> np.ndarray:
    """(n, D) postures from one (n,) column per DOF name; every DOF of ``model`` must be given."""
    missing = set(model.dof_names) - set(cols)
    if missing:
        raise ValueError(f"the movement gives no values for {sorted(missing)}")
    return np.stack([cols[name] for name in model.dof_names], axis=1)


def _cycle(keys: tuple[tuple[float, float], ...], phase: np.ndarray, harmonics: int = 4) -> np.ndarray:
    """A smooth periodic curve through ``keys`` (% of cycle, value): the first
    ``harmonics`` Fourier terms of their periodic linear interpolation, at ``phase`` (0..1)."""
    grid = np.arange(200) / 200
    x, y = np.array(keys, dtype=float).T
    coeffs = np.fft.rfft(np.interp(grid * 100, x, y))[: harmonics + 1] / len(grid)
    k = np.arange(harmonics + 1)
    terms = coeffs[None, :] * np.exp(2j * np.pi * k[None, :] * phase[:, None])
    return (terms[:, 0] + 2 * terms[:, 1:].sum(axis=1)).real


# ---- spider: alternating tetrapod gait ----------------------------------------------------------

# Per leg pair 1-4: centre and amplitude (degrees) of coxa yaw (promotion +), coxa pitch,
# femur pitch (levation +), patella pitch (flexion -), tibia yaw, metatarsus pitch.
_SPIDER_DOFS = ("coxa_yaw", "coxa_pitch", "femur_pitch", "patella_pitch", "tibia_yaw",
                "metatarsus_pitch")
_SPIDER_CENTRE = {"1": (5, 5, 35, -50, 0, -30), "2": (0, 5, 35, -55, 0, -30),
                  "3": (-5, 5, 38, -60, 0, -30), "4": (-8, 5, 35, -50, 0, -25)}
_SPIDER_AMPLITUDE = {"1": (15, 4, 10, 15, 6, 12), "2": (14, 4, 10, 12, 6, 10),
                     "3": (14, 4, 10, 12, 6, 10), "4": (16, 4, 10, 15, 6, 12)}
# Phase leads over promotion (yaw = A cos phase; swing while it grows): levation in swing;
# front legs extend the patella reaching forward, hind legs at push-off.
_SPIDER_LEAD = {"1": 0.0, "2": 0.0, "3": np.pi, "4": np.pi}
_TETRAPOD = {"L1": 0.0, "R2": 0.0, "L3": 0.0, "R4": 0.0, "R1": 0.5, "L2": 0.5, "R3": 0.5, "L4": 0.5}
_SPIDER_STEP_HZ = (2.5, 4.5)
_SPIDER_PASS_MM = 36.0
_SPIDER_SPEED = (25.0, 45.0)  # mm/s


def spider_walk(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """A wolf spider walking across the arena in an alternating tetrapod gait (L1 R2 L3 R4
    half a cycle from R1 L2 R3 L4), the step rate drifting within 2.5-4.5 Hz; each leg DOF a
    sinusoid of the step phase about a drifting centre with drifting gain (as the fly's);
    the cephalothorax on passes of 36 mm at 25-45 mm/s, heading ±35° and turning up to
    ±25°/s (a new pass restarts at the other end: a jump, like a new trial), bobbing
    ±0.3 mm twice per stride, yawing ±3°, rolling ±2° per stride, pitching; the abdomen swaying.
    """
    fps = subject.fps
    t = np.arange(n) / fps
    rate = _smooth_noise(rng, t, 1.0, *_SPIDER_STEP_HZ)
    phase = 2 * np.pi * np.cumsum(rate) / fps + rng.uniform(0, 2 * np.pi)
    names = subject.model.dof_names
    q = np.zeros((n, len(names)))
    cols: dict[str, np.ndarray] = {k: np.empty(n) for k in ("ceph_tx", "ceph_tz", "ceph_yaw")}
    start = 0
    while start < n:
        speed = rng.uniform(*_SPIDER_SPEED)
        length = min(n - start, int(_SPIDER_PASS_MM / speed * fps))
        tt = np.arange(length) / fps
        heading = np.radians(rng.uniform(-35, 35) + rng.uniform(-25, 25) * tt)
        step = speed / fps
        x = np.cumsum(step * np.cos(heading)) - step
        z = np.cumsum(-step * np.sin(heading))
        # centre the pass on the arena, a little to one side
        x = x - 0.5 * _SPIDER_PASS_MM * np.cos(heading[0])
        z = z + 0.5 * _SPIDER_PASS_MM * np.sin(heading[0]) + rng.uniform(-5, 5)
        cols["ceph_tx"][start:start + length] = x
        cols["ceph_tz"][start:start + length] = z
        cols["ceph_yaw"][start:start + length] = np.degrees(heading)
        start += length
    q[:, names.index("ceph_tx")] = cols["ceph_tx"]
    q[:, names.index("ceph_tz")] = cols["ceph_tz"]
    q[:, names.index("ceph_yaw")] = cols["ceph_yaw"] + _smooth_noise(rng, t, 1.0, -5, 5) + 3 * np.cos(phase)
    q[:, names.index("ceph_ty")] = -0.5 + 0.3 * np.cos(2 * phase)
    q[:, names.index("ceph_roll")] = 2 * np.cos(phase - 0.3 * np.pi)
    q[:, names.index("ceph_pitch")] = _smooth_noise(rng, t, 2.0, -3, 3) + 1.5 * np.cos(2 * phase)
    q[:, names.index("abd_yaw")] = _smooth_noise(rng, t, 1.5, -6, 6) - 2 * np.cos(phase)
    q[:, names.index("abd_pitch")] = _smooth_noise(rng, t, 2.0, -10, 5) + np.cos(2 * phase)
    for leg, offset in _TETRAPOD.items():
        pair, mirror = leg[1], 1.0 if leg[0] == "R" else -1.0
        lead = (0.0, np.pi / 2, np.pi / 2, _SPIDER_LEAD[pair], np.pi / 3, _SPIDER_LEAD[pair] + 0.3)
        for k, dof in enumerate(_SPIDER_DOFS):
            gain = _smooth_noise(rng, t, 1.0, 0.7, 1.15)
            drift = _smooth_noise(rng, t, 1.0, -0.4, 0.4) * _SPIDER_AMPLITUDE[pair][k]
            value = _SPIDER_CENTRE[pair][k] + drift + gain * _SPIDER_AMPLITUDE[pair][k] * np.cos(
                phase + 2 * np.pi * offset + lead[k])
            sign = mirror if dof in ("coxa_yaw", "tibia_yaw") else 1.0
            q[:, names.index(f"{leg}_{dof}")] = sign * value
    return _inside(subject.model, q)


# ---- helpers -------------------------------------------------------------------------------------


def _smooth_noise(rng: np.random.Generator, t: np.ndarray, period_s: float, lo: float,
                  hi: float) -> np.ndarray:
    """A smooth random signal in [lo, hi] varying over about ``period_s``: a random phase
    sum of three sinusoids of periods around ``period_s``."""
    waves = sum(np.sin(2 * np.pi * t / (period_s * f) + rng.uniform(0, 2 * np.pi))
                for f in rng.uniform(0.7, 2.0, 3))
    return lo + (hi - lo) * (waves / 6 + 0.5)


def _inside(model: KinematicModel, q: np.ndarray) -> np.ndarray:
    """``q`` after checking it keeps every DOF 1 % of its range inside its limits."""
    span = model.upper - model.lower
    lo, hi = model.lower + 0.01 * span, model.upper - 0.01 * span
    bad = np.flatnonzero(np.any((q < lo) | (q > hi), axis=0))
    if len(bad):
        raise ValueError(f"the movement leaves the range of {[model.dof_names[i] for i in bad]}")
    return q
