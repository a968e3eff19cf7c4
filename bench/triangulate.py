"""Triangulated branch starts on the hexapod (issue 13 item 1): how often are they right, at what cost.

    python bench/triangulate.py [--cameras 6 3 2] [--images N] [--ghosts N] [--seed S] [--fit]

Renders and detects the hexapod like ``bench/animals.py`` (5 px markers, ``--ghosts`` ghost
blobs per view), triangulates every image's blobs (``core.triangulate``) and poses each leg
onto the candidates from the histogram mean (``core.epipolar_start``), the leg's base frame
taken from the *true* thorax posture (the fitted thorax is within a fraction of a degree:
docs/BENCH_SUBJECTS.md). Prints, per camera count: how many true markers have a candidate,
candidates per image, the share of leg starts with every DOF within 5° of the truth, the
share whose Eq. 5 error is below the leg's SA stop ε (and how many of those are wrong), and
the CPU time per image of triangulation and of the starts. With ``--fit``, also fits the
images (``core.sequence.fit_sequence``, ``mocap fit``'s defaults, which try these starts itself:
``core.treefit``) and counts the legs the fit gets wrong (a DOF > 5° off) that the start
gets right.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.animals import angle_errors, fit, render_and_detect
from bench.subjects import load
from core import _kernels
from core.anneal import search_space
from core.epipolar_start import branch_start
from core.error import view_offsets
from core.fit import FitParams
from core.histogram import Histograms
from core.part_objective import EPS_PROJECTIONS
from core.tree import decompose
from core.triangulate import triangulate

FOUND_FRACTION = 0.02  # a true marker is found when a candidate lies within this × the leg's reach


def measure(cameras: int, args: argparse.Namespace) -> None:
    subject = load("hexapod", cameras)
    model, rig = subject.model, subject.rig
    tree = decompose(model)
    space = search_space(model, Histograms.uniform(model, prior_weight=100.0))
    params = FitParams()
    off = view_offsets(None, rig)
    data = render_and_detect(subject, args.images, soft=False, ghosts=args.ghosts,
                             rng=np.random.default_rng(args.seed))
    found_at = FOUND_FRACTION * float(np.median([b.reach for b in tree.branches]))
    starts = np.full((args.images, len(model.dofs)), np.nan)
    below_eps = np.zeros((args.images, len(tree.branches)), dtype=bool)
    n_found = n_markers = n_candidates = 0
    cpu_tri = cpu_ik = 0.0
    for i, (q, det) in enumerate(zip(data.truth, data.detections, strict=True)):
        t0 = time.process_time()
        cand = triangulate(det, rig=rig)
        t1 = time.process_time()
        cpu_tri += t1 - t0
        n_candidates += len(cand)
        markers = model.marker_positions(q)
        for b in tree.branches:
            d = np.linalg.norm(markers[b.markers][:, None] - cand.points[None], axis=2)
            n_found += int(np.sum(d.min(axis=1, initial=np.inf) <= found_at))
            n_markers += len(b.markers)
        rot, pos = np.empty((len(model.joints), 3, 3)), np.empty((len(model.joints), 3))
        _kernels.forward_kinematics(q, model.arrays, rot, pos)
        views_seen = int(np.count_nonzero(det.counts))
        t1 = time.process_time()
        for k, b in enumerate(tree.branches):
            start = branch_start(cand, part=b, rotation=rot[b.base], origin=pos[b.base],
                                 q0=space.mean[b.dofs], model=model, rig=rig,
                                 points=det.kernel_points, start=det.start, offsets=off,
                                 empty_view_penalty_px=params.empty_view_penalty_px)
            if start is not None:
                starts[i, b.dofs] = start.dofs
                eps = params.anneal.eps * len(b.markers) * views_seen / EPS_PROJECTIONS
                below_eps[i, k] = start.error <= eps
        cpu_ik += time.process_time() - t1
    if tree.trunk is not None:
        starts[:, tree.trunk.dofs] = data.truth[:, tree.trunk.dofs]
    start_ok = _legs_within(model, tree, starts, data.truth)
    n_legs = start_ok.size
    print(f"\n== hexapod, {cameras} cameras: {args.images} images, {args.ghosts} ghost blobs per view, "
          f"{len(tree.branches)} legs")
    print(f"  true markers with a candidate within {found_at:.3g} {model.units}: "
          f"{100 * n_found / n_markers:.1f} % ({n_found}/{n_markers})")
    print(f"  candidates per image: {n_candidates / args.images:.1f} "
          f"(true markers per image: {len(model.markers)})")
    print(f"  leg starts with every DOF within 5 deg: {100 * start_ok.mean():.1f} % "
          f"({int(start_ok.sum())}/{n_legs})")
    print(f"  leg starts with Eq. 5 <= the leg's eps: {100 * below_eps.mean():.1f} % "
          f"({int(below_eps.sum())}/{n_legs}); of those, > 5 deg off: "
          f"{int(np.sum(below_eps & ~start_ok))}")
    print(f"  CPU per image: triangulation {1e3 * cpu_tri / args.images:.2f} ms, "
          f"starts of all legs {1e3 * cpu_ik / args.images:.2f} ms")
    if args.fit:
        result, timing = fit(subject, data, seed=args.seed, jobs=1)
        fitted = np.array([f.dofs for f in result.fits])
        fit_ok = _legs_within(model, tree, fitted, data.truth)
        print(f"  fit (mocap fit defaults): legs with every DOF within 5 deg "
              f"{100 * fit_ok.mean():.1f} %, images {100 * fit_ok.all(axis=1).mean():.1f} %; "
              f"legs the fit gets wrong and the start right: "
              f"{int(np.sum(~fit_ok & start_ok))} of {int(np.sum(~fit_ok))}; "
              f"fit CPU per image {1e3 * timing['cpu'] / args.images:.0f} ms")


def _legs_within(model, tree, postures: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(T, B) bool: every DOF of leg b within 5 degrees of the truth in image t (NaN: not)."""
    err = np.abs(angle_errors(model, postures, truth))
    err[np.isnan(err)] = np.inf
    return np.stack([np.all(err[:, b.dofs] <= 5.0, axis=1) for b in tree.branches], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, nargs="+", choices=(6, 3, 2), default=[6, 3, 2])
    parser.add_argument("--images", type=int, default=50)
    parser.add_argument("--ghosts", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fit", action="store_true", help="also fit the images and compare")
    args = parser.parse_args()
    if args.images < 1 or args.ghosts < 0:
        parser.error("--images must be >= 1, --ghosts >= 0")
    print(f"bench/triangulate.py: seed {args.seed}; CPU times are process_time (one core)")
    for cameras in args.cameras:
        measure(cameras, args)


if __name__ == "__main__":
    main()
