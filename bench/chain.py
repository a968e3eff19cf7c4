"""Many-joint chains: a tail of N joints (paper §4's "larger number of joints").

    python bench/chain.py [--segments 4 8 12 16] [--images 40] [--seed 0] [--ghosts 2]
        [--soft-tissue] [--occlusion F]

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
conditions (no unmodelled marker).
Prints ``bench/animals.py``'s table per N; every image's fit goes to
``bench/out/chain-<N>[-soft][-occ<percent>].csv``.
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


def tail_xml(segments: int) -> str:
    """A fixed body (markers at x = -10 and 0 mm) with a tail of ``segments`` joints along +x."""
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
    return "\n".join(['<model name="tail" units="mm">', *joints, *markers, "</model>"])


def tail_rig() -> Rig:
    """Three cameras 120° apart, 30° above the point 30 mm along the tail, 300 mm from it."""
    target = (30.0, 0.0, 0.0)
    radius, height = 300.0 * np.cos(np.radians(30)), 300.0 * np.sin(np.radians(30))
    return Rig.from_dict(ring(["c0", "c1", "c2"], [90, 210, 330], radius=radius, height=height,
                             target=target, f=1000.0, size=SIZE, dist=(0, 0, 0, 0, 0)))


def wave(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, D) a travelling wave: yaw and pitch of joint k lag k / (N - 1) of a quarter cycle."""
    segments = len(subject.model.dofs) // 2
    t = np.arange(n)[:, None] / subject.fps + rng.uniform(0, 1 / WAVE_HZ)
    lag = PHASE_ALONG * np.arange(segments)[None, :] / max(segments - 1, 1)
    q = np.empty((n, 2 * segments))
    q[:, 0::2] = YAW_DEG / segments * np.sin(2 * np.pi * WAVE_HZ * t - lag)
    q[:, 1::2] = PITCH_DEG / segments * np.sin(2 * np.pi * WAVE_HZ * t - lag + np.pi / 3)
    return q


def tail(segments: int) -> Subject:
    return Subject(f"tail-{segments}", KinematicModel.from_xml(tail_xml(segments)), tail_rig(),
                   (SIZE,) * 3, FPS, wave, ())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, nargs="+", default=[4, 8, 12, 16])
    parser.add_argument("--images", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ghosts", type=int, default=None, help="default 2, or 0 with --soft-tissue")
    parser.add_argument("--soft-tissue", action="store_true")
    parser.add_argument("--occlusion", type=float, default=0.0, metavar="F")
    args = parser.parse_args()
    if args.ghosts is None:
        args.ghosts = 0 if args.soft_tissue else 2
    if args.images < 1 or args.ghosts < 0 or min(args.segments) < 2 or not 0 <= args.occlusion <= 0.5:
        parser.error("--images must be >= 1, --ghosts >= 0, --segments >= 2, --occlusion in [0, 0.5]")
    for segments in args.segments:
        subject = tail(segments)
        data = render_and_detect(subject, args.images, soft=args.soft_tissue, ghosts=args.ghosts,
                                 rng=np.random.default_rng(args.seed), occlusion=args.occlusion)
        result, timing = fit(subject, data, seed=args.seed, jobs=1)
        OUT.mkdir(parents=True, exist_ok=True)
        csv_path = OUT / (f"chain-{segments}" + ("-soft" if args.soft_tissue else "")
                          + (f"-occ{round(100 * args.occlusion)}" if args.occlusion else "") + ".csv")
        write_angles_csv(csv_path, subject.model, result.fits, SampleClock(subject.fps))
        label = (f"tail of {segments} segments" + (" + soft tissue" if args.soft_tissue else "")
                 + (f" + {100 * args.occlusion:g} % hidden" if args.occlusion else ""))
        report(subject, label, data, result, timing, csv_path, soft=args.soft_tissue)


if __name__ == "__main__":
    main()
