"""Why images are off with real markers: a wrong basin, or the minimum itself moved?

    python bench/basins.py --subject stick|locust|biped|fullbody|hexapod|freefly|rat|mouse|spider
        [--images N] [--soft-tissue] [--cameras 6|4|3|2] [--occlusion F [--everywhere] [--hidden-run S]]
        [--glints N]
        [--off DEG] [--fps HZ] [--seed S] [--huber PX] [--model-error F] [--rig-error PX]
        [--beyond F]

Renders and fits a subject as ``bench/animals.py`` does (same seed, same images), then
refines the *true* posture on every image (``core.treefit.refine_whole``, as a fit's last
step): the minimum nearest the truth. Prints

- its median and 90th-percentile absolute DOF error and its share of images with every DOF
  within 5° (what no choice of basin can beat with this objective), beside the fitted
  postures' and the best of each image's candidates' (fit and alternatives: what a perfect
  choice by continuity would give);
- why each image more than 5° off is off (:func:`why_off`): the truth's own minimum is as
  far off (the image's limit), a candidate within 5° was passed over by the choice by
  continuity, the search missed a lower minimum near the truth, or the image holds a
  minimum as low as the truth's elsewhere and no attempt found the truth's;
- for every image more than ``--off`` degrees (10) off reported ``ok``: its objective and
  tolerance, the fit's and the true posture's Eq. 5 read as blobs (``core.error.view_error``
  with the fit's fusion distance: the objective without a lost marker), the refined truth's
  objective, how far it lies from the truth and from the fit (0: the truth's basin is the
  fit's: the minimum moved), and whether an alternative was given. A truth that scores
  below the fit means the search stopped short; one that scores above it, or slides onto
  it when refined, means the objective's minimum is not at the truth.

``--huber`` refines the truth with another least-squares radius than the fit's (1 px): how
much a loss closer to least squares would move the minimum nearest the truth.
``--model-error`` and ``--rig-error`` fit (and refine the truth) with the model and rig off
as ``bench/animals.py`` does: is a lab's imperfect model the images' limit, or the search's?
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.animals import (
    OCCLUSION_RUN_S,
    WITHIN_DEG,
    as_measured,
    cut_at_edge,
    fit,
    fit_params,
    render_and_detect,
)
from bench.subjects import NAMES, camera_choice, load
from core.ambiguity import angle_gaps
from core.error import view_error, view_offsets
from core.fit import Status, alternative_tolerance, tolerance_readings
from core.treefit import refine_whole

REASONS = ("the truth's own minimum is off too",
           f"a candidate within {WITHIN_DEG:g} deg passed over by the choice",
           "a lower minimum near the truth missed by the search",
           "a minimum as low as the truth's kept, the truth's not found")


def _summary(label: str, errors: np.ndarray) -> None:
    """``errors`` (T, R): absolute rotational DOF errors (degrees) of T images."""
    print(f"  {label:<46} median {np.median(errors):6.2f}   90th percentile "
          f"{np.percentile(errors, 90, method='higher'):6.2f}   within {WITHIN_DEG:g} deg "
          f"{100 * np.mean(errors.max(axis=1) <= WITHIN_DEG):5.1f} %")


def why_off(nearest_off: float, best_off: float, lowest: float, truth_objective: float,
            floor: float) -> str:
    """Why an image more than :data:`WITHIN_DEG` off is off, one of :data:`REASONS`: its
    refined truth (``nearest_off`` degrees off the truth, objective ``truth_objective`` px)
    is off too; else its best candidate is within it (``best_off``); else the refined truth
    scores lower than the lowest candidate (``lowest`` px, the attempts' best before the
    choice by continuity) by more than ``floor`` px (the fixed alternative tolerance: what
    any image tells apart); else the image holds a minimum as low as the truth's elsewhere.
    """
    if nearest_off > WITHIN_DEG:
        return REASONS[0]
    if best_off <= WITHIN_DEG:
        return REASONS[1]
    return REASONS[2] if truth_objective < lowest - floor else REASONS[3]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subject", choices=NAMES, required=True)
    parser.add_argument("--images", type=int, default=300)
    parser.add_argument("--soft-tissue", action="store_true")
    parser.add_argument("--cameras", type=int, choices=(6, 4, 3, 2), default=None,
                        help="fly or spider cameras (default 6 and 4) or rat cameras (default 3)")
    parser.add_argument("--occlusion", type=float, default=0.0, metavar="F",
                        help="fraction of marker projections hidden, as bench/animals.py")
    parser.add_argument("--hidden-run", type=float, default=OCCLUSION_RUN_S, metavar="S",
                        help="with --occlusion, the mean hidden run, seconds, as bench/animals.py")
    parser.add_argument("--everywhere", action="store_true",
                        help="with --occlusion, hide each marker from every view at once")
    parser.add_argument("--glints", type=int, default=0, metavar="N",
                        help="reflections per view and image on the body, as bench/animals.py")
    parser.add_argument("--off", type=float, default=10.0,
                        help="degrees: list the ok images this far off (5: the noise-free target)")
    parser.add_argument("--fps", type=float, default=None, help="the movement's frame rate")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--huber", type=float, default=None, help="px, for the truth's refinement")
    parser.add_argument("--model-error", type=float, default=0.0, metavar="F",
                        help="fit with segment lengths and marker placements off by N(0, F)")
    parser.add_argument("--rig-error", type=float, default=0.0, metavar="PX",
                        help="fit with every view's image shifted by PX pixels")
    parser.add_argument("--beyond", type=float, default=0.0, metavar="F",
                        help="the share of each view's marker projections beyond its frame's edge")
    args = parser.parse_args()
    subject = load(args.subject, camera_choice(args.subject, args.cameras))
    if args.fps:
        subject = replace(subject, fps=args.fps)
    if args.beyond:
        subject = cut_at_edge(subject, subject.trajectory(args.images, np.random.default_rng(args.seed)),
                              args.beyond)
    data = render_and_detect(subject, args.images, soft=args.soft_tissue,
                             ghosts=0 if args.soft_tissue else 2,
                             rng=np.random.default_rng(args.seed), occlusion=args.occlusion,
                             hidden_run_s=args.hidden_run,
                             everywhere=args.everywhere, glints=args.glints)
    subject = as_measured(subject, args)
    model, rig, rot = subject.model, subject.rig, subject.model.rotational
    result, _ = fit(subject, data, seed=args.seed, jobs=1)
    params = fit_params(data)[0]
    truth_params = params if args.huber is None else replace(
        params, anneal=replace(params.anneal, huber_px=args.huber))
    off = view_offsets(None, rig)
    fitted, nearest, best, rows, reasons = [], [], [], [], Counter()
    for fit_, det, truth in zip(result.fits, data.detections, data.truth, strict=True):
        q, _, objective = refine_whole(truth.copy(), det, model, rig, truth_params, off)
        gaps = angle_gaps(fit_.dofs, truth)[rot]
        fitted.append(gaps)
        nearest.append(angle_gaps(q, truth)[rot])
        best.append(min((angle_gaps(c, truth)[rot] for c in
                         (fit_.dofs, *(a.dofs for a in fit_.alternatives))), key=np.max))
        if gaps.max() > WITHIN_DEG:
            candidates = [fit_.as_candidate(), *fit_.alternatives]
            choosable = min(angle_gaps(c.dofs, truth)[rot].max() for c in candidates if c.minimum)
            floor = tolerance_readings(params, det, model, fit_.error, len(model.dofs))[0]
            reasons[why_off(nearest[-1].max(), choosable, min(c.objective for c in candidates),
                            objective, floor)] += 1
        if fit_.status is Status.OK and gaps.max() > args.off:
            seen = fit_.error - fit_.outside[1]  # without the projections beyond the edges, as core.fit
            tolerance = alternative_tolerance(params, det, model, seen, len(model.dofs))
            blobs = [view_error(q_, det, model=model, rig=rig, fusion_px=params.fusion_px,
                                empty_view_penalty_px=params.empty_view_penalty_px)
                     for q_ in (fit_.dofs, truth)]
            rows.append((fit_.sample, gaps.max(), fit_.objective, tolerance, *blobs, objective,
                         angle_gaps(q, truth)[rot].max(), angle_gaps(q, fit_.dofs)[rot].max(),
                         fit_.alternative_deg(rot)))
    print(f"\n== {' '.join(sys.argv[1:])}: absolute DOF error (deg), every rotational DOF of every "
          "image")
    _summary("fitted (chosen by continuity)", np.array(fitted))
    _summary("best of each image's candidates", np.array(best))
    _summary("minimum nearest the truth (truth refined)", np.array(nearest))
    print(f"\n  images more than {WITHIN_DEG:g} deg off: {sum(reasons.values())}")
    for reason in REASONS:
        print(f"    {reason:<62} {reasons[reason]:4d}")
    print(f"\n  images more than {args.off:g} deg off reported ok: {len(rows)}")
    print("  sample  off   objective  tolerance  as blobs: fit   truth  truth refined: objective"
          "  off  from fit   alternative_deg")
    for s, err, obj, tol, b_fit, b_truth, r_obj, r_truth, r_fit, alt in rows:
        print(f"  {s:6d} {err:5.1f} {obj:10.2f} {tol:10.2f} {b_fit:15.2f} {b_truth:7.2f} "
              f"{r_obj:25.2f} {r_truth:5.1f} {r_fit:9.1f} {alt:14.1f}")



if __name__ == "__main__":
    main()
