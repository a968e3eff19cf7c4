"""Many-joint chains: a tail of N joints (paper §4's "larger number of joints").

    python bench/chain.py [--segments 4 8 12 16] [--images 40] [--seed 0] [--ghosts 2]
        [--soft-tissue] [--occlusion F] [--limbs]

The whole-animal subjects (``bench/animals.py``) split into parts of 2-7 DOFs, so they do
not show how the fit scales along one chain: ``core.tree`` keeps a chain of up to
``MAX_PART_DOFS`` DOFs one part, searched by SA at once, and cuts a longer one into
segments fitted one after another (``core.tree._segments``).

The subject: a mouse-sized tail, 80 mm in N segments of 80 / N mm, each joint a yaw and a
pitch, one marker at each segment's end, on a fixed body with three markers; three pinhole
cameras 30° above it, 640×480, about 3.3 px per mm. It swings in a travelling wave, 2 Hz,
a quarter cycle along the tail, the whole tail bending by up to 90° of yaw and 45° of
pitch: each joint by 1 / N of that, within a range 2.5 times as wide either way. Filmed at
100 Hz, rendered with 5 px markers and ``--ghosts`` ghost blobs per view, detected and
fitted as ``bench/animals.py`` does; ``--soft-tissue`` and ``--occlusion`` are its
conditions (no unmodelled marker). With ``--limbs`` the chain is a spine: two hind limbs
on the body and two forelimbs on its last joint (hip 3 DOFs, knee, ankle; markers on the
thigh, knee, ankle and toe), each DOF swinging at 2 Hz through 10-90 % of its range; the
spine is then a branch's own trunk, and the forelimbs hang from it.
Prints ``bench/animals.py``'s table per N; every image's fit goes to
``bench/out/chain-<N>[-limbs][-soft][-occ<percent>].csv``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.animals import OUT, fit, render_and_detect, report
from bench.subjects import Subject
from bench.subjects.build import ring
from core.model import KinematicModel
from core.results import SampleClock, write_angles_csv
from core.rig import Rig

TAIL_MM = 80.0
SIZE = (640, 480)
FPS = 100.0
WAVE_HZ = 2.0
YAW_DEG, PITCH_DEG = 90.0, 45.0  # the whole tail's bend: the sum of its joints' amplitudes
RANGE = 2.5  # a joint's range is this many times its amplitude either way
PHASE_ALONG = np.pi / 2  # phase lag from the first joint to the last
LIMB_MM = (15.0, 17.0, 8.0)  # a limb's thigh, shank and foot (--limbs)


def limb_xml(name: str, parent: str, x: float, z: float) -> tuple[list[str], list[str]]:
    """A limb hanging down (-y) from (x, 0, z) of joint ``parent``: its joints and markers."""
    thigh, shank, foot = LIMB_MM
    joints = [
        f'<joint name="{name}_hip" parent="{parent}"><offset x="{x:g}" y="0" z="{z:g}"/>'
        f'<rest z="-90"/><dof axis="z" name="{name}_flex" min="-40" max="40"/>'
        f'<dof axis="y" name="{name}_rot" min="-20" max="20"/>'
        f'<dof axis="x" name="{name}_abd" min="-20" max="20"/></joint>',
        f'<joint name="{name}_knee" parent="{name}_hip"><offset x="{thigh:g}" y="0" z="0"/>'
        f'<dof axis="z" name="{name}_knee" min="-100" max="-10"/></joint>',
        f'<joint name="{name}_ankle" parent="{name}_knee"><offset x="{shank:g}" y="0" z="0"/>'
        f'<dof axis="z" name="{name}_ankle" min="20" max="90"/></joint>',
        f'<joint name="{name}_toe" parent="{name}_ankle"><offset x="{foot:g}" y="0" z="0"/></joint>',
    ]
    markers = [f'<marker name="{name}_thigh" joint="{name}_hip" x="{thigh / 2:g}" y="2" z="0"/>'] + [
        f'<marker name="{name}_{j}" joint="{name}_{j}" x="0" y="0" z="0"/>' for j in ("knee", "ankle", "toe")]
    return joints, markers


def tail_xml(segments: int, limbs: bool = False) -> str:
    """A fixed body (markers at x = -10 and 0 mm) with a tail of ``segments`` joints along +x;
    with ``limbs``, a spine: hind limbs on the body, forelimbs on its end."""
    length = TAIL_MM / segments
    yaw, pitch = RANGE * YAW_DEG / segments, RANGE * PITCH_DEG / segments
    joints = ['<joint name="body"/>']
    parent = "body"
    for k in range(segments):
        joints.append(
            f'<joint name="s{k}" parent="{parent}"><offset x="{length if k else 5.0:g}" y="0" z="0"/>'
            f'<dof axis="y" name="yaw{k}" min="{-yaw:g}" max="{yaw:g}"/>'
            f'<dof axis="z" name="pitch{k}" min="{-pitch:g}" max="{pitch:g}"/></joint>')
        parent = f"s{k}"
    joints.append(f'<joint name="tip" parent="{parent}"><offset x="{length:g}" y="0" z="0"/></joint>')
    ends = [f"s{k}" for k in range(1, segments)] + ["tip"]
    markers = [f'<marker name="m{k}" joint="{joint}" x="0" y="0" z="0"/>' for k, joint in enumerate(ends)]
    markers += ['<marker name="B0" joint="body" x="-10" y="2" z="0"/>',
                '<marker name="B1" joint="body" x="0" y="3" z="-3"/>',
                '<marker name="B2" joint="body" x="0" y="3" z="3"/>']
    for name, at, x in (("LH", "body", -5.0), ("RH", "body", -5.0), ("LF", "tip", 0.0), ("RF", "tip", 0.0)):
        if limbs:
            limb_joints, limb_markers = limb_xml(name, at, x, -6.0 if name[0] == "L" else 6.0)
            joints += limb_joints
            markers += limb_markers
    return "\n".join(['<model name="tail" units="mm">', *joints, *markers, "</model>"])


def tail_rig(limbs: bool = False) -> Rig:
    """Three cameras 120° apart, 30° above the point 30 mm along the tail, 300 mm from it;
    for a spine with limbs, above a point 15 mm lower, at 0.9 times the focal length."""
    target = (30.0, -15.0 if limbs else 0.0, 0.0)
    radius, height = 300.0 * np.cos(np.radians(30)), 300.0 * np.sin(np.radians(30)) + target[1]
    return Rig.from_dict(ring(["c0", "c1", "c2"], [90, 210, 330], radius=radius, height=height,
                             target=target, f=900.0 if limbs else 1000.0, size=SIZE, dist=(0, 0, 0, 0, 0)))


def wave(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, D) a travelling wave: yaw and pitch of joint k lag k / (N - 1) of a quarter cycle;
    a limb's DOFs swing through 10-90 % of their ranges at the same rate, each its own phase."""
    model = subject.model
    yaw = np.array([d.name.startswith("yaw") for d in model.dofs])
    pitch = np.array([d.name.startswith("pitch") for d in model.dofs])
    segments = int(yaw.sum())
    t = np.arange(n)[:, None] / subject.fps + rng.uniform(0, 1 / WAVE_HZ)
    lag = PHASE_ALONG * np.arange(segments)[None, :] / max(segments - 1, 1)
    phase = rng.uniform(0, 2 * np.pi, len(model.dofs))
    q = model.lower + (model.upper - model.lower) * (0.5 + 0.4 * np.sin(2 * np.pi * WAVE_HZ * t + phase))
    q[:, yaw] = YAW_DEG / segments * np.sin(2 * np.pi * WAVE_HZ * t - lag)
    q[:, pitch] = PITCH_DEG / segments * np.sin(2 * np.pi * WAVE_HZ * t - lag + np.pi / 3)
    return q


def tail(segments: int, limbs: bool = False) -> Subject:
    """The tail of ``segments`` joints, or with ``limbs`` the spine, as a benchmark subject."""
    model = KinematicModel.from_xml(tail_xml(segments, limbs))
    return Subject(f"{'spine' if limbs else 'tail'}-{segments}", model, tail_rig(limbs), (SIZE,) * 3, FPS,
                   wave, ())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, nargs="+", default=[4, 8, 12, 16])
    parser.add_argument("--images", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ghosts", type=int, default=None, help="default 2, or 0 with --soft-tissue")
    parser.add_argument("--soft-tissue", action="store_true")
    parser.add_argument("--occlusion", type=float, default=0.0, metavar="F")
    parser.add_argument("--limbs", action="store_true", help="a spine with hind limbs and forelimbs")
    args = parser.parse_args()
    if args.ghosts is None:
        args.ghosts = 0 if args.soft_tissue else 2
    if args.images < 1 or args.ghosts < 0 or min(args.segments) < 2 or not 0 <= args.occlusion <= 0.5:
        parser.error("--images must be >= 1, --ghosts >= 0, --segments >= 2, --occlusion in [0, 0.5]")
    for segments in args.segments:
        subject = tail(segments, args.limbs)
        data = render_and_detect(subject, args.images, soft=args.soft_tissue, ghosts=args.ghosts,
                                 rng=np.random.default_rng(args.seed), occlusion=args.occlusion)
        result, timing = fit(subject, data, seed=args.seed, jobs=1)
        OUT.mkdir(parents=True, exist_ok=True)
        csv_path = OUT / (f"chain-{segments}" + ("-limbs" if args.limbs else "")
                          + ("-soft" if args.soft_tissue else "")
                          + (f"-occ{round(100 * args.occlusion)}" if args.occlusion else "") + ".csv")
        write_angles_csv(csv_path, subject.model, result.fits, SampleClock(subject.fps))
        label = (f"{'spine' if args.limbs else 'tail'} of {segments} segments"
                 + (" with limbs" if args.limbs else "") + (" + soft tissue" if args.soft_tissue else "")
                 + (f" + {100 * args.occlusion:g} % hidden" if args.occlusion else ""))
        report(subject, label, data, result, timing, csv_path, soft=args.soft_tissue)


if __name__ == "__main__":
    main()
