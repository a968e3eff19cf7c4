"""Do images more than 10° off get an alternative? The witness measured on many postures.

    python bench/witness.py [--subject NAME|all] [--images N] [--px 2 4] [--cameras 6|3|2] [--seed S]

For each of ``--images`` postures of the subject's movement, every model marker slides by its
own 3D offset (a normal direction, scaled so that the image displacement over every view is
``--px`` RMS: a skin marker that slides, seen alike by every camera), and the true posture is
refined on the exact projections of the slid markers (``core.treefit.refine_whole``): the
minimum nearest the truth, what the image itself says, whatever a search would find. No ghost
blobs, no unmodelled markers, no search, so each image takes milliseconds and a few hundred
give a share to the percent.

On each refined posture, ``core.undetermined.undetermined_alternative`` looks for a witness
(a posture ≥ 10° away in some DOF within the image's tolerance) twice: with each DOF's
interval the wider of the residual's two readings (``core.undetermined.shared_scatter_inflation``,
as ``mocap fit`` does) and with the residual read as scatter independent in every projection
only. Prints, per subject and slide: images whose refined posture is more than 10° off the
truth, how many of those get no witness under each reading (the issue: never ``ok`` with no
alternative), and the share of all images given a witness (what the flag costs in images
that a lab will see marked ambiguous). Statuses are not computed: an image's status depends on
its error alone, and every image here may be ``ok``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.subjects import NAMES, Subject, camera_choice, load
from core.ambiguity import Candidate, angle_gaps
from core.error import Detections, view_offsets
from core.fit import FitParams, witness_tolerance
from core.treefit import refine_whole
from core.undetermined import (
    UNDETERMINED_DEG,
    scatter_error,
    undetermined_alternative,
)

REFINE_STEPS = 30  # LM steps from the truth into the slid markers' minimum


def slid_detections(subject: Subject, q: np.ndarray, px: float, rng: np.random.Generator) -> Detections:
    """The exact projections of the model's markers at posture ``q`` (D,), each slid by a
    random 3D offset scaled to ``px`` RMS image displacement over every view."""
    model, rig = subject.model, subject.rig
    positions = model.marker_positions(q)
    slide = rng.normal(size=positions.shape)
    base = rig.project(positions)
    slide *= px / np.sqrt(np.mean(np.sum((rig.project(positions + slide) - base) ** 2, axis=-1)))
    return Detections.from_views(list(rig.project(positions + slide)))


def witnesses(subject: Subject, det: Detections, q: np.ndarray,
              params: FitParams) -> tuple[np.ndarray, tuple[bool, bool]]:
    """The true posture ``q`` refined on ``det``, and whether a witness is found with the
    shared reading and with the independent reading alone."""
    model, rig = subject.model, subject.rig
    off = view_offsets(None, rig)
    fit, error, objective = refine_whole(q.copy(), det, model, rig, params, off, steps=REFINE_STEPS)
    scatter = scatter_error(fit, det, model, rig, off, params.empty_view_penalty_px, params.fusion_px)
    _, residual = witness_tolerance(params, det, model, scatter)
    found = tuple(undetermined_alternative(
        Candidate(fit, error, objective), det, model=model, rig=rig,
        floor_px=params.alternative_tolerance_px, residual_px=residual, inflate=inflate,
        fusion_px=params.fusion_px, empty_view_penalty_px=params.empty_view_penalty_px,
        huber_px=params.anneal.huber_px,
    ) is not None for inflate in (True, False))
    return fit, (found[0], found[1])


def run(name: str, cameras: int | None, images: int, px: float, seed: int) -> None:
    subject = load(name, camera_choice(name, cameras))
    truth = subject.trajectory(images, np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    params = FitParams()
    off = np.zeros(images, bool)
    found = np.zeros((images, 2), bool)
    for t, q in enumerate(truth):
        fit, found[t] = witnesses(subject, slid_detections(subject, q, px, rng), q, params)
        off[t] = angle_gaps(fit, q)[subject.model.rotational].max() > UNDETERMINED_DEG
    label = name + (f" ({subject.rig.n_videos} cameras)" if cameras else "")
    print(f"{label:<22} {px:4.1f} px  {images:5d} images  {int(off.sum()):4d} > 10° off  "
          f"no witness: shared {int((off & ~found[:, 0]).sum()):3d}, "
          f"independent {int((off & ~found[:, 1]).sum()):3d}   "
          f"witnessed: shared {100 * found[:, 0].mean():5.1f} %, "
          f"independent {100 * found[:, 1].mean():5.1f} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--subject", choices=[*NAMES, "all"], default="all")
    parser.add_argument("--images", type=int, default=200)
    parser.add_argument("--px", type=float, nargs="+", default=[2.0, 4.0],
                        help="RMS image displacement of the slid markers")
    parser.add_argument("--cameras", type=int, choices=(6, 3, 2))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for name in NAMES if args.subject == "all" else [args.subject]:
        for px in args.px:
            run(name, args.cameras if name in ("hexapod", "rat") else None, args.images, px,
                args.seed)


if __name__ == "__main__":
    main()
