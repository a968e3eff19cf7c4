"""Random kinematic trees: does the engine hold on animals it was not built around?

    python bench/random_trees.py [--models 8] [--images 40] [--seed 0] [--cameras 3]
        [--rig ring|side-top] [--distortion K1] [--markers 1|2] [--occlusion F] [--fps 100]
        [--soft-tissue] [--glints N] [--beyond F] [--model-error F] [--rig-error PX]

The subjects of ``bench/animals.py`` are nine animals; labs bring others. Each model here
is drawn at random: a root with three markers, fixed or (two models in five) free with
three translations and three rotations; one to six branches spread around it, each a
chain of two to four joints of one to three Euler DOFs on random axes (the first joint two
or three), ranges of 15-60° either way, segments of 4-12 mm.

``--markers 1``: one marker per segment, on its axis half the time. Such a model leaves
rolls undetermined in every posture, so its images are mostly ambiguous; what counts is
that none more than 10° off is reported ``ok`` without an alternative.
``--markers 2``: two markers per segment, off its axis, and at most two DOFs per joint
after a branch's first: a model whose images should determine it, so its accuracy counts
too.

The cameras stand on a ring 35° above the root, 250 mm away (800×600 px, f = 1400 px:
about 5.6 px per mm), or with ``--rig side-top`` two such cameras 80° apart, one 5° above
the root and one 85° above it (a side and a top view, as a camera and a mirror give: limbs
seen end-on from above pile their markers onto merged blobs); ``--distortion K1`` gives
every lens OpenCV's radial coefficients k1 = K1, k2 = 0.1 |K1| (-0.3: a wide-angle lens's
barrel, about 19 px at the corners of these images); the movement is
``core.synth.natural_movements`` at ``--fps``. The
images are rendered, detected and fitted as ``bench/animals.py`` does (5 px markers, 2
ghost blobs per view, ``--occlusion`` as there; ``--soft-tissue`` as there: every marker
slides 2 px RMS, no ghost blobs, an unmodelled marker on the root, :data:`UNMODELLED`;
``--glints`` as there: reflections on the segments; ``--beyond`` as there: every view's roi ending
where the share F of its projections lies beyond; ``--model-error`` as there: the model fitted
is measured, its segment lengths and marker placements off by N(0, F), and the line adds the
median distance of the fit from inverse kinematics given the labels with that model,
``bench/reference.py``; ``--rig-error`` as there: every view of the rig fitted shifted).
Prints one line per model (DOFs, the parts ``core.tree`` fits, the median absolute
rotational DOF error, the worst image, the share of images with every DOF within 5°,
``ok`` images more than 10° off without an alternative, statuses, fit images per CPU
second) and the totals.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.animals import (
    OUT,
    ambiguous_flags,
    angle_errors,
    as_measured,
    cut_at_edge,
    far_off_unflagged,
    fit,
    render_and_detect,
)
from bench.reference import labelled_postures
from bench.subjects import Subject
from bench.subjects.build import ring
from core.fit import Status
from core.model import KinematicModel
from core.results import SampleClock, write_angles_csv
from core.rig import Rig
from core.synth import natural_movements

SIZE = (800, 600)
FREE_ROOT_SHARE = 0.4
FREE_ROOT = ('<dof axis="tx" name="tx" min="-10" max="10"/><dof axis="ty" name="ty" min="-10" max="10"/>'
             '<dof axis="tz" name="tz" min="-5" max="5"/><dof axis="z" name="rz" min="-40" max="40"/>'
             '<dof axis="y" name="ry" min="-15" max="15"/><dof axis="x" name="rx" min="-15" max="15"/>')
ROOT_MARKERS = ((12.0, 0.0, 2.0), (-12.0, 0.0, 2.0), (0.0, 4.0, 4.0))  # mm
BRANCH_RADIUS_MM = 8.0  # where the branches leave the root
UNMODELLED = (("root", (0.0, -5.0, 3.0)),)  # a skin marker the model lacks (mm), with --soft-tissue


def random_model(rng: np.random.Generator, markers: int) -> KinematicModel:
    """A random tree (module docstring) with ``markers`` (1 or 2) markers per segment."""
    root = FREE_ROOT if rng.random() < FREE_ROOT_SHARE else ""
    joints = ['<model name="random" units="mm">', f'<joint name="root">{root}</joint>']
    marks = [f'<marker name="R{i}" joint="root" x="{x:g}" y="{y:g}" z="{z:g}"/>'
             for i, (x, y, z) in enumerate(ROOT_MARKERS)]
    branches = int(rng.integers(1, 7))
    for b in range(branches):
        heading = 2 * np.pi * b / branches + rng.normal(0.0, 0.2)
        parent = "root"
        for j in range(int(rng.integers(2, 5))):
            name = f"b{b}j{j}"
            joints.append(_joint(rng, name, parent, heading if j == 0 else None, markers))
            marks += _segment_markers(rng, name, markers)
            parent = name
    return KinematicModel.from_xml("\n".join([*joints, *marks, "</model>"]))


def _joint(rng: np.random.Generator, name: str, parent: str, heading: float | None, markers: int) -> str:
    """One joint: a branch's first (``heading``, radians about z) at the root's edge, else
    at the end of its parent's 4-12 mm segment; its DOFs on distinct random axes."""
    if heading is not None:
        n_dofs = int(rng.choice([2, 3])) if markers == 1 else 3
        x, y = BRANCH_RADIUS_MM * np.cos(heading), BRANCH_RADIUS_MM * np.sin(heading)
        place = f'<offset x="{x:.1f}" y="{y:.1f}" z="0"/><rest z="{np.degrees(heading):.0f}"/>'
    else:
        n_dofs = int(rng.choice([1, 1, 2, 2, 3])) if markers == 1 else int(rng.choice([1, 2]))
        place = f'<offset x="{rng.uniform(4.0, 12.0):.1f}" y="0" z="0"/>'
    dofs = "".join(f'<dof axis="{axis}" name="{name}_{axis}" min="{-rng.uniform(15, 60):.0f}" '
                   f'max="{rng.uniform(15, 60):.0f}"/>' for axis in rng.permutation(["x", "y", "z"])[:n_dofs])
    return f'<joint name="{name}" parent="{parent}">{place}{dofs}</joint>'


def _segment_markers(rng: np.random.Generator, joint: str, markers: int) -> list[str]:
    """The markers of the segment that ``joint`` moves (it runs along its x axis)."""
    length = rng.uniform(4.0, 12.0)
    if markers == 1 and rng.random() < 0.5:
        at = [(length, 0.0, 0.0)]  # on the axis: the segment's roll is not seen
    else:
        at = [(length * rng.uniform(0.4, 1.0), rng.normal(0.0, 1.5), rng.normal(0.0, 1.5))]
    if markers == 2:
        at.append((0.4 * length, rng.choice([-1.0, 1.0]) * rng.uniform(1.5, 3.0), rng.normal(0.0, 1.0)))
    return [f'<marker name="{joint}_m{k}" joint="{joint}" x="{x:.1f}" y="{y:.1f}" z="{z:.1f}"/>'
            for k, (x, y, z) in enumerate(at)]


def ring_rig(cameras: int, k1: float = 0.0) -> Rig:
    """``cameras`` pinhole cameras on a ring 35° above the origin (:func:`_aimed`)."""
    azimuths = list(np.linspace(0.0, 360.0, cameras, endpoint=False) + 20.0)
    return _aimed([f"c{k}" for k in range(cameras)], azimuths, [35.0] * cameras, k1)


def side_top_rig(k1: float = 0.0) -> Rig:
    """Two pinhole cameras at one azimuth, 5° and 85° above the origin (:func:`_aimed`)."""
    return _aimed(["side", "top"], [20.0, 20.0], [5.0, 85.0], k1)


def _aimed(names: list[str], azimuths: list[float], elevations: list[float], k1: float) -> Rig:
    """Pinhole cameras ``names`` aimed at the origin from 250 mm, at ``azimuths`` and
    ``elevations`` (degrees), f = 1400 px, :data:`SIZE` images, their lenses' radial
    distortion k1 (k2 = 0.1 |k1|)."""
    up = np.radians(elevations)
    return Rig.from_dict(ring(names, azimuths, radius=250.0 * np.cos(up), height=250.0 * np.sin(up),
                              target=(0.0, 0.0, 0.0), f=1400.0, size=SIZE, dist=_lens(k1)))


def _lens(k1: float) -> tuple[float, ...]:
    """OpenCV's distortion coefficients (k1, k2, p1, p2, k3) of a lens of radial ``k1``."""
    return (k1, 0.1 * abs(k1), 0.0, 0.0, 0.0)


def _natural(subject: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
    return natural_movements(subject.model, subject.rig, n, rng=rng, fps=subject.fps, frame_size=SIZE)


def filmed(model: KinematicModel, cameras: int, fps: float, rig: str = "ring", k1: float = 0.0) -> Subject:
    """``model`` filmed by :func:`ring_rig` (or, ``rig`` "side-top", :func:`side_top_rig`),
    lenses of radial distortion ``k1``, at ``fps``, moving naturally, with the
    :data:`UNMODELLED` marker (drawn only under sliding skin, ``bench.animals``)."""
    views = side_top_rig(k1) if rig == "side-top" else ring_rig(cameras, k1)
    return Subject("random", model, views, (SIZE,) * len(views.views), fps, _natural, UNMODELLED)


def run_model(model: KinematicModel, args: argparse.Namespace, rng: np.random.Generator) -> dict:
    """Render, detect and fit ``args.images`` images of ``model``; the figures of its line."""
    subject = filmed(model, args.cameras, args.fps, args.rig, args.distortion)
    if args.beyond:  # the movement render_and_detect will draw from rng, drawn from a copy
        subject = cut_at_edge(subject, subject.trajectory(args.images, copy.deepcopy(rng)), args.beyond)
    data = render_and_detect(subject, args.images, soft=args.soft_tissue, ghosts=0 if args.soft_tissue else 2,
                             rng=rng, occlusion=args.occlusion, glints=args.glints)
    measured = as_measured(subject, args)
    result, timing = fit(measured, data, seed=args.seed, jobs=1)
    csv_path = OUT / "random-tree.csv"
    OUT.mkdir(parents=True, exist_ok=True)
    write_angles_csv(csv_path, model, result.fits, SampleClock(subject.fps))
    fitted = np.array([f.dofs for f in result.fits])
    errors = np.abs(angle_errors(model, fitted, data.truth)[:, model.rotational])  # (T, R) degrees
    worst = errors.max(axis=1)
    ok = np.array([f.status is Status.OK for f in result.fits])
    flagged = ambiguous_flags(result, csv_path)[0]
    figures = {"errors": errors, "worst": worst, "ok": ok, "flagged": flagged, "cpu": timing["cpu"],
               "parts": [len(p.dofs) for p in model.tree.parts] if model.tree else [len(model.dofs)]}
    if args.model_error:
        reference = labelled_postures(measured.model, data.markers, data.truth)
        figures["from_reference"] = np.abs(angle_errors(model, fitted, reference)[:, model.rotational])
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=int, default=8)
    parser.add_argument("--images", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cameras", type=int, default=3)
    parser.add_argument("--rig", choices=("ring", "side-top"), default="ring",
                        help="cameras on a ring 35° up (default), or a side and a top view (2 cameras)")
    parser.add_argument("--distortion", type=float, default=0.0, metavar="K1",
                        help="every lens's radial distortion k1 (k2 = 0.1 |k1|; default 0)")
    parser.add_argument("--markers", type=int, choices=(1, 2), default=2, help="markers per segment")
    parser.add_argument("--occlusion", type=float, default=0.0, metavar="F")
    parser.add_argument("--fps", type=float, default=100.0)
    parser.add_argument("--soft-tissue", action="store_true",
                        help="markers slide 2 px RMS; an unmodelled marker; no ghost blobs")
    parser.add_argument("--glints", type=int, default=0, metavar="N",
                        help="reflections off the body per view and image, on its segments")
    parser.add_argument("--beyond", type=float, default=0.0, metavar="F",
                        help="the share of each view's marker projections beyond its frame's edge (a roi)")
    parser.add_argument("--model-error", type=float, default=0.0, metavar="F",
                        help="fit with segment lengths and marker placements off by N(0, F)")
    parser.add_argument("--rig-error", type=float, default=0.0, metavar="PX",
                        help="fit with every view's image shifted by PX pixels")
    args = parser.parse_args()
    if (args.models < 1 or args.images < 1 or args.cameras < 2 or args.glints < 0
            or not 0 <= args.occlusion <= 0.5 or not 0 <= args.beyond <= 0.5
            or not (0 <= args.model_error <= 0.5 and 0 <= args.rig_error <= 50)):
        parser.error("--models and --images must be >= 1, --cameras >= 2, --glints >= 0, --occlusion "
                     "and --beyond in [0, 0.5], --model-error in [0, 0.5], --rig-error in [0, 50]")
    if not -0.5 <= args.distortion <= 0.5:
        parser.error("--distortion must lie in [-0.5, 0.5]")
    if args.rig == "side-top" and args.cameras != 2:
        parser.error("--rig side-top has 2 cameras: give --cameras 2")
    print(f"bench/random_trees.py: seed {args.seed}, {args.models} models, {args.images} images each, "
          f"{args.cameras} cameras" + (" (a side and a top view)" if args.rig == "side-top" else "")
          + (f", lens distortion k1 {args.distortion:g}" if args.distortion else "")
          + f", {args.markers} marker(s) per segment, {100 * args.occlusion:g} % hidden"
          + (", sliding skin" if args.soft_tissue else "")
          + (f", {args.glints} glints per view" if args.glints else "")
          + (f", {100 * args.beyond:g} % beyond the frames' edge" if args.beyond else "")
          + (f", model off {100 * args.model_error:g} %" if args.model_error else "")
          + (f", rig off {args.rig_error:g} px" if args.rig_error else ""))
    totals = {"images": 0, "within": 0, "bad": 0, "cpu": 0.0}
    errors = []
    for k in range(args.models):
        rng = np.random.default_rng([args.seed, k])
        model = random_model(rng, args.markers)
        r = run_model(model, args, rng)
        bad = far_off_unflagged(r["worst"], r["ok"], r["flagged"])
        n = len(r["worst"])
        errors.append(r["errors"].ravel())
        print(f"model {k}: {len(model.dofs)} DOFs, parts {r['parts']}; median error "
              f"{np.median(r['errors']):.2f} deg, worst image "
              f"{r['worst'].max():.1f} deg, {100 * np.mean(r['worst'] <= 5.0):.0f} % within 5 deg; "
              f"ok > 10 deg off without an "
              f"alternative: {len(bad)} {bad.tolist()}; over threshold {int(np.sum(~r['ok']))}, "
              f"ambiguous {int(r['flagged'].sum())}; {n / r['cpu']:.0f} images per CPU s"
              + (f"; from labelled IK median {np.median(r['from_reference']):.2f} deg"
                 if "from_reference" in r else ""), flush=True)
        totals["images"] += n
        totals["within"] += int(np.sum(r["worst"] <= 5.0))
        totals["bad"] += len(bad)
        totals["cpu"] += r["cpu"]
    every = np.concatenate(errors)
    within = 100 * totals["within"] / totals["images"]
    print(f"all: {totals['images']} images, median error {np.median(every):.2f} deg, 90th percentile "
          f"{np.percentile(every, 90):.2f} deg, {within:.1f} % within 5 deg, "
          f"{totals['bad']} ok > 10 deg off without an alternative (target 0), "
          f"{totals['images'] / totals['cpu']:.1f} images per CPU s")


if __name__ == "__main__":
    main()
