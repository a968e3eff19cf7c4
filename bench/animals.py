"""Whole-animal accuracy and speed benchmark (issue 13): subjects from published anatomy.

    python bench/animals.py [--subject hexapod|freefly|biped|fullbody|stick|locust|rat|mouse|spider|all]
        [--images N] [--cameras 6|4|3|2] [--soft-tissue] [--ghosts N]
        [--occlusion F [--everywhere] [--hidden-run S]]
        [--lost-claw] [--glints N] [--beyond F] [--seed S] [--jobs 1]
        [--threshold auto|otsu|100] [--model-error F] [--rig-error PX]

Each subject (``bench/subjects``, sources in ``docs/BENCH_SUBJECTS.md``) moves naturally,
is rendered by ``core.synth`` (5 px markers, ``--ghosts`` ghost blobs per view and image:
2, or 0 with soft tissue),
detected by ``core.detect`` and fitted by ``core.sequence.fit_sequence`` with the settings
``mocap fit`` uses by default (marker diameter estimated from the blobs; ``--threshold``
sets the detector's). With
``--soft-tissue`` every marker slides by a slowly varying 3D offset whose image displacement
is 2 px RMS, and the markers the model lacks (one; the rat and the mouse two) are drawn in
every view.
With ``--occlusion F`` every (view, marker) pair, the unmodelled markers included, is hidden
(not drawn: no blob) in runs of images, as a leg hides a marker from one camera: a two-state
Markov chain per pair, hidden a fraction F of the images on average, in runs of
:data:`OCCLUSION_RUN_S` seconds on average (``--hidden-run``; at least 2 images), started from its stationary
state and drawn from the run's generator after the images' noise generators are spawned, so
the images differ from those of F = 0 by the hidden blobs only. With ``--everywhere`` the
chain is one per marker and hides it from every view at once (a claw tucked under the body,
a marker that fell off): the DOFs it alone places are then not determined, and the figures
say whether such images are flagged. With ``--lost-claw`` the first branch's last marker (a
claw or a toe in most subjects) is missing from every view of every image, as a marker
that fell off before the trial (:func:`lost_marker`). With ``--glints N``, N reflections
per view and image lie on the animal's segments (:func:`glint_pixels`), among the markers
where a lab's clutter is, unlike the ghosts drawn anywhere in the view.
With ``--beyond F`` each view sees only the part of its frame (or roi) left of the column
beyond which the share F of its markers' projections over the movement lies: a roi there,
so that legs walk out of the frame and back (:func:`cut_at_edge`); the fit is given the rois.
With ``--model-error F`` the fit is given the subject's model with every segment length and
marker placement off by a relative N(0, F) (a model measured by hand), and with
``--rig-error PX`` its rig with every view's image shifted by PX pixels (a calibration's
error); the images are rendered with the true ones (``bench/imperfect.py``).
Prints, per subject, the per-DOF RMSE and the issue's figures next to its targets (with
``--soft-tissue`` or ``--model-error``, also how far the truth and the fit lie from inverse
kinematics given the labels, ``bench/reference.py``: what a labelled pipeline reports), and
writes every image's fit to
``bench/out/animals-<subject>[-<cameras>cams][-soft][-occ<percent>[all]]…[-glints<N>][-beyond<percent>].csv``
(angles.csv).
"""

from __future__ import annotations

import argparse
import csv
import gc
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.imperfect import calibrated_rig, measured_model
from bench.reference import labelled_postures
from bench.subjects import NAMES, Subject, camera_choice, load
from core.detect import DetectorParams, detect, marker_diameter, restored_at_edges
from core.error import Detections, fusion_distance
from core.fit import FitParams, ImageFit, Status
from core.histogram import Histograms
from core.model import KinematicModel, Marker
from core.results import SampleClock, write_angles_csv
from core.rig import Rig
from core.sequence import SequenceResult, fit_sequence
from core.synth import render_frames
from core.warmup import compile_kernels

OUT = Path(__file__).resolve().parent / "out"
MARKER_DIAMETER_PX = 5.0
SOFT_TISSUE_PX = 2.0  # RMS image displacement of the skin markers
SOFT_TISSUE_PERIOD_S = 1.0  # the offsets vary over about this long
OCCLUSION_RUN_S = 0.05  # mean length of a marker's hidden run in one view

# Targets of issue 13.
TARGET_MEDIAN_RMSE = 0.5  # degrees
TARGET_WORST_RMSE = 2.0
TARGET_WITHIN_5 = 0.99
TARGET_HEXAPOD_RATE = 100.0  # images/s on one core, 6 cameras
TARGET_SOFT_MEDIAN = 1.5  # degrees, median absolute DOF error with soft tissue
TARGET_SOFT_P90 = 5.0
FAR_OFF_DEG = 10.0  # an image this far off the truth must never be `ok` without an alternative
WITHIN_DEG = 5.0  # an image is right when every rotational DOF is this close to the truth


@dataclass
class Rendered:
    """A subject's images, detected, and the truth behind them."""

    truth: np.ndarray  # (T, D) degrees, model units
    detections: list[Detections]
    detect_seconds: float
    hidden: np.ndarray | None = None  # (T, V, M) bool: marker m not drawn in view v (occlusion)
    markers: np.ndarray | None = None  # (T, M, 3) the model's markers as drawn (slid), model units


def render_and_detect(subject: Subject, n: int, *, soft: bool, ghosts: int,
                      rng: np.random.Generator, occlusion: float = 0.0, everywhere: bool = False,
                      detector: DetectorParams = DetectorParams(),
                      marker_px: float = MARKER_DIAMETER_PX, lost_claw: bool = False,
                      glints: int = 0, hidden_run_s: float = OCCLUSION_RUN_S) -> Rendered:
    """Render ``n`` images of the subject's movement in every camera, then detect them (timed).

    ``occlusion``: the fraction of (image, view, marker) hidden (:func:`occlusion_mask`), each
    marker from every view at once with ``everywhere``, in runs of ``hidden_run_s`` seconds on
    average (at least 2 images).
    ``lost_claw``: :func:`lost_marker` hidden from every view of every image too.
    ``detector``: the detection settings (``mocap fit``'s defaults unless given).
    ``marker_px``: the markers' imaged diameter, pixels.
    ``glints``: reflections off the animal's body per view and image (:func:`glint_pixels`),
    drawn after everything else is drawn from ``rng``.
    """
    truth = subject.trajectory(n, rng)
    model, offsets, markers = subject.model, None, subject.model.marker_positions(truth)
    if soft:
        model = subject.with_unmodelled_markers()
        slide = soft_tissue_slide(subject, truth, rng)
        offsets, markers = soft_tissue_offsets(subject, truth, slide), markers + slide
    noise = rng.spawn(subject.rig.n_videos)
    hidden = None
    if occlusion > 0:
        mean_run = max(2.0, hidden_run_s * subject.fps)
        views = len(subject.rig.views)
        hidden = occlusion_mask((n, 1 if everywhere else views, len(model.markers)), occlusion,
                                mean_run, rng)
        hidden = np.repeat(hidden, views, axis=1) if everywhere else hidden
    if lost_claw:
        hidden = np.zeros((n, len(subject.rig.views), len(model.markers)), bool) if hidden is None else hidden
        hidden[:, :, lost_marker(subject.model)] = True
    if glints:
        model, offsets, drop = _with_glints(subject, model, truth, offsets, hidden,
                                            glint_pixels(subject, truth, glints, marker_px, rng))
    else:
        drop = hidden
    frames = [
        render_frames(model, subject.rig, truth, rng=r, video=k, frame_size=subject.size_of(k),
                      marker_diameter_px=marker_px, ghosts_per_view=ghosts,
                      drop=drop, marker_offsets_px=offsets)
        for k, r in enumerate(noise)
    ]
    detections, seconds = [], 0.0
    for image in zip(*frames, strict=True):
        t0 = time.perf_counter()
        detections.append(detect(list(image), rig=subject.rig, params=detector))
        seconds += time.perf_counter() - t0
    t0 = time.perf_counter()  # blobs cut by a view's edge restored, as `mocap fit`'s source does
    diameter = marker_diameter(detections[:50]) or 0.0
    detections = [restored_at_edges(d, subject.rig, diameter) for d in detections]
    return Rendered(truth, detections, seconds + time.perf_counter() - t0, hidden, markers)


def glint_pixels(subject: Subject, truth: np.ndarray, per_view: int, marker_px: float,
                 rng: np.random.Generator) -> np.ndarray:
    """(T, V, per_view, 2) image points of reflections off the animal's body (cuticle, fur,
    skin): each at a uniformly random place on a random segment of the posture ``truth``
    (T, D) (a joint to a child joint or to one of its markers), moved across by up to
    ``marker_px`` pixels, drawn anew for every view and image (a glint depends on where the
    camera and the light are, and comes and goes as the limb turns). Unlike ``--ghosts``,
    which fall anywhere in the view, these lie where markers lie: among the legs."""
    model = subject.model
    index = {j.name: i for i, j in enumerate(model.joints)}
    ends = [(index[j.parent], i, False) for i, j in enumerate(model.joints) if j.parent is not None]
    ends += [(index[m.joint], k, True) for k, m in enumerate(model.markers)]
    n, views = len(truth), len(subject.rig.views)
    joints = np.array([model.joint_transforms(q)[:, :3, 3] for q in truth])  # (T, J, 3)
    markers = model.marker_positions(truth)  # (T, M, 3)
    pick = rng.integers(len(ends), size=(n, views, per_view))
    base = np.array([e[0] for e in ends])[pick]
    tip = np.array([e[1] for e in ends])[pick]
    on_marker = np.array([e[2] for e in ends])[pick]
    t = np.arange(n)[:, None, None]
    a = joints[t, base]
    b = np.where(on_marker[..., None], markers[t, np.where(on_marker, tip, 0)],
                 joints[t, np.where(on_marker, 0, tip)])
    points = a + rng.random((n, views, per_view, 1)) * (b - a)  # (T, V, G, 3)
    flat = subject.rig.project(points.reshape(n, views * per_view, 3))  # (T, V, V·G, 2)
    own = flat.reshape(n, views, views, per_view, 2)[:, np.arange(views), np.arange(views)]
    angle = rng.uniform(0, 2 * np.pi, (n, views, per_view))
    radius = marker_px * np.sqrt(rng.random((n, views, per_view)))
    return own + radius[..., None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def _with_glints(subject: Subject, model: KinematicModel, truth: np.ndarray, offsets: np.ndarray | None,
                 hidden: np.ndarray | None, glints: np.ndarray
                 ) -> tuple[KinematicModel, np.ndarray, np.ndarray | None]:
    """The rendering model, marker offsets and drop mask with the glints ``glints``
    (T, V, G, 2) drawn as markers: G markers at the root's origin, offset in each view and
    image onto their glint, never hidden."""
    root = next(j.name for j in model.joints if j.parent is None)
    g = glints.shape[2]
    drawn = replace(model, markers=(*model.markers,
                                    *(Marker(f"glint{i + 1}", root, (0.0, 0.0, 0.0)) for i in range(g))))
    at = subject.rig.project(drawn.marker_positions(truth)[:, -g:])  # (T, V, G, 2)
    n, views = glints.shape[:2]
    before = np.zeros((n, views, len(model.markers), 2)) if offsets is None else offsets
    drop = None if hidden is None else np.concatenate([hidden, np.zeros((n, views, g), bool)], axis=2)
    return drawn, np.concatenate([before, glints - at], axis=2), drop


def lost_marker(model: KinematicModel) -> int:
    """The index of the last marker of ``model.tree``'s first branch, or of a single chain:
    a claw or a toe in most subjects (the spider's abdomen tip), a marker a lab finds gone
    and one that alone places a DOF in most subjects."""
    return int(model.tree.branches[0].markers[-1]) if model.tree is not None else len(model.markers) - 1


def occlusion_mask(shape: tuple[int, int, int], fraction: float, mean_run: float,
                   rng: np.random.Generator) -> np.ndarray:
    """(T, V, M) bool, True where marker m is hidden from view v in image t.

    Each (view, marker) pair is an independent two-state Markov chain over the images: a
    hidden marker reappears with probability ``1 / mean_run`` per image (hidden runs last
    ``mean_run`` images on average, geometric), a visible one disappears with the
    probability that makes ``fraction`` the stationary hidden share, and the first image
    is drawn from that stationary share. Raises ValueError when no chain has both (a
    fraction above ``mean_run / (mean_run + 1)`` would need runs of visibility shorter
    than one image).
    """
    if not (0.0 <= fraction < 1.0 and mean_run >= 1.0) or fraction / (1.0 - fraction) > mean_run:
        raise ValueError(f"no hidden fraction {fraction} with hidden runs of {mean_run} images")
    leave = 1.0 / mean_run
    enter = fraction * leave / (1.0 - fraction)
    draws = rng.random(shape)
    hidden = np.empty(shape, dtype=bool)
    hidden[0] = draws[0] < fraction
    for t in range(1, shape[0]):
        hidden[t] = np.where(hidden[t - 1], draws[t] >= leave, draws[t] < enter)
    return hidden


def soft_tissue_slide(subject: Subject, truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(T, M, 3) the model markers' slide over the skin, model units, world frame.

    Each model marker slides by a 3D offset, a sum of three random-direction sinusoids
    of periods near :data:`SOFT_TISSUE_PERIOD_S`, scaled so that its image displacement
    over every view and image is :data:`SOFT_TISSUE_PX` RMS.
    """
    n, m = len(truth), len(subject.model.markers)
    t = np.arange(n)[:, None, None] / subject.fps
    slide = np.zeros((n, m, 3))
    for _ in range(3):
        direction = rng.normal(size=(m, 3))
        period = SOFT_TISSUE_PERIOD_S * rng.uniform(0.5, 2.0, (m, 1))
        slide += direction * np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi, (m, 1)))
    positions = subject.model.marker_positions(truth)
    base = subject.rig.project(positions)
    for _ in range(2):  # projection is nearly linear in the small offset: rescale once more
        shifted = subject.rig.project(positions + slide) - base
        slide *= SOFT_TISSUE_PX / np.sqrt(np.mean(np.sum(shifted**2, axis=-1)))
    return slide


def soft_tissue_offsets(subject: Subject, truth: np.ndarray, slide: np.ndarray) -> np.ndarray:
    """(T, V, M + K, 2) pixel offsets of the skin markers slid by ``slide`` (T, M, 3) from
    their places in the postures ``truth`` (T, D) (the K unmodelled ones last, at 0)."""
    positions = subject.model.marker_positions(truth)
    base = subject.rig.project(positions)
    offsets = np.zeros((*base.shape[:2], base.shape[2] + len(subject.unmodelled), 2))
    offsets[:, :, : base.shape[2]] = subject.rig.project(positions + slide) - base
    return offsets


def fit_params(data: Rendered) -> tuple[FitParams, float]:
    """``mocap fit``'s default settings for these images, and the marker diameter (px) they
    were estimated from (the blobs of the first 50 images)."""
    diameter = marker_diameter(data.detections[:50]) or 0.0
    return FitParams(fusion_px=fusion_distance(diameter)), diameter


def fit(subject: Subject, data: Rendered, *, seed: int, jobs: int) -> tuple[SequenceResult, dict]:
    """Fit like ``mocap fit`` with default settings; returns the result and its timings."""
    params, diameter = fit_params(data)
    prior = Histograms.uniform(subject.model, prior_weight=100.0)
    kwargs = dict(model=subject.model, rig=subject.rig, histograms=prior, params=params, seed=seed)
    # Compile, or load from numba's cache, every kernel outside the timing, as `mocap fit` does
    # before its first image (a kernel first needed by the 40th image loads inside it, else),
    # then collect the garbage: the first collection of every generation after numba's
    # loading scans some 10^5 objects (about 0.1 s), once per process.
    compile_kernels()
    gc.collect()
    done = [0]

    def progress(_: ImageFit) -> None:
        done[0] += 1
        print(f"\r  fitted {done[0]}/{len(data.detections)}", end="", file=sys.stderr, flush=True)

    wall, cpu = time.perf_counter(), _cpu_seconds()
    if jobs == 1:
        result = fit_sequence(data.detections, progress=progress, **kwargs)
    else:
        chunk = max(1, math.ceil(len(data.detections) / (4 * jobs)))
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            result = fit_sequence(data.detections, chunk_size=chunk, map_chunks=pool.map, **kwargs)
    timing = {"wall": time.perf_counter() - wall, "cpu": _cpu_seconds() - cpu,
              "diameter": diameter}
    print("\r", end="", file=sys.stderr)
    return result, timing


def _cpu_seconds() -> float:
    """CPU seconds of this process and of its finished children (the ``--jobs`` processes)."""
    t = os.times()  # children: 10 ms ticks; this process: process_time's finer clock
    return time.process_time() + t.children_user + t.children_system


def angle_errors(model, fitted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(T, D) fitted minus true; rotational DOFs wrapped into [-180, 180) degrees."""
    err = fitted - truth
    rot = model.rotational
    err[:, rot] = (err[:, rot] + 180.0) % 360.0 - 180.0
    return err


def far_off_unflagged(worst: np.ndarray, ok: np.ndarray, flagged: np.ndarray) -> np.ndarray:
    """Indices of the images that break issue 13's rule: more than :data:`FAR_OFF_DEG` off
    the truth in some rotational DOF (``worst`` (T,) degrees), reported ``ok`` (``ok`` (T,)
    bool) and not marked ambiguous (``flagged`` (T,) bool False)."""
    return np.flatnonzero(ok & ~flagged & (worst > FAR_OFF_DEG))


def fit_flags(result: SequenceResult, rotational: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ok, flagged), each (T,) bool, read from the fits themselves: status ``ok``; an
    alternative given (``ImageFit.alternative_deg`` finite, the column FORMATS §3 writes)."""
    ok = np.array([f.status is Status.OK for f in result.fits])
    return ok, np.array([math.isfinite(f.alternative_deg(rotational)) for f in result.fits])


def ambiguous_flags(result: SequenceResult, csv_path: Path) -> tuple[np.ndarray, str]:
    """(T,) bool, images marked ambiguous: a non-empty ``alternative_deg`` in angles.csv when
    the writer gives that column (FORMATS §3), else fits with non-empty ``alternatives``."""
    with csv_path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if rows and "alternative_deg" in rows[0]:
        return np.array([r["alternative_deg"] != "" for r in rows]), "alternative_deg"
    return np.array([bool(f.alternatives) for f in result.fits]), "alternatives"


def report(subject: Subject, label: str, data: Rendered, result: SequenceResult, timing: dict,
           csv_path: Path, *, soft: bool, reference: np.ndarray | None = None) -> None:
    """Print the subject's table: per-DOF RMSE, then the issue's figures beside its targets,
    and with ``reference`` ((T, D), ``bench.reference.labelled_postures``) how far the fit and
    the truth each lie from what inverse kinematics given the labels reports."""
    model, n = subject.model, len(data.detections)
    fitted = np.array([f.dofs for f in result.fits])
    err = angle_errors(model, fitted, data.truth)
    rot = model.rotational
    failed = ~np.all(np.isfinite(fitted), axis=1)
    err[failed] = np.inf  # an image without a posture counts as wrong, everywhere
    rmse = np.sqrt(np.mean(err**2, axis=0))
    print(f"\n== {label}: {n} images, {len(subject.rig.views)} views, {len(model.dofs)} DOFs, "
          f"{len(model.markers)} markers, marker diameter {timing['diameter']:.2f} px (estimated)")
    print("per-DOF RMSE (degrees; translations in model units):")
    cells = [f"{name:>22} {rmse[i]:8.3f}{'' if rot[i] else ' ' + model.units}"
             for i, name in enumerate(model.dof_names)]
    for i in range(0, len(cells), 3):
        print("".join(cells[i : i + 3]))
    abs_rot = np.abs(err[:, rot])
    worst_dof = int(np.argmax(np.where(rot, rmse, -np.inf)))
    per_image = abs_rot.max(axis=1)
    worst_image = int(np.argmax(per_image))
    statuses = [f.status for f in result.fits]
    ok = np.array([s is Status.OK for s in statuses])
    flagged, source = ambiguous_flags(result, csv_path)
    off_ok = int(np.sum(ok & (per_image > FAR_OFF_DEG)))
    off_ok_unflagged = len(far_off_unflagged(per_image, ok, flagged))
    ambiguous = int(flagged.sum())
    median_rmse = float(np.median(rmse[rot]))
    within = float(np.mean(per_image <= WITHIN_DEG))
    rate_wall, rate_cpu = n / timing["wall"], n / timing["cpu"]

    def line(what: str, value: str, target: str = "", met: bool | None = None,
             ratio: float | None = None) -> None:
        verdict = "" if met is None else ("met" if met else "NOT MET")
        if met is not None and ratio is not None:
            verdict += f" (measured/target {ratio:.3g})"
        print(f"  {what:<44}{value:>16}   {target:<18}{verdict}")

    def target(text: str, met: bool, ratio: float | None = None) -> tuple:
        """The noise-free targets apply without soft tissue only."""
        return (text, met, ratio) if not soft else ("", None, None)

    print(f"  {'':<44}{'measured':>16}   {'target':<18}")
    line("median DOF RMSE (deg)", f"{median_rmse:.3f}",
         *target(f"<= {TARGET_MEDIAN_RMSE}", median_rmse <= TARGET_MEDIAN_RMSE,
                 median_rmse / TARGET_MEDIAN_RMSE))
    line(f"worst DOF RMSE (deg): {model.dof_names[worst_dof]}", f"{rmse[worst_dof]:.3f}",
         *target(f"<= {TARGET_WORST_RMSE}", rmse[worst_dof] <= TARGET_WORST_RMSE,
                 rmse[worst_dof] / TARGET_WORST_RMSE))
    line(f"worst image: sample {worst_image}, max abs DOF error", f"{per_image[worst_image]:.2f}")
    line("images with every DOF within 5 deg", f"{100 * within:.1f} %",
         *target(f">= {100 * TARGET_WITHIN_5:.0f} %", within >= TARGET_WITHIN_5))
    line("images > 10 deg off, ok, no alternative given", f"{off_ok_unflagged}", "0",
         off_ok_unflagged == 0)
    line("images > 10 deg off, ok (with or without an alternative)", f"{off_ok}")
    if soft:
        med = float(np.median(abs_rot))  # failed images count as infinitely wrong
        p90 = float(np.percentile(abs_rot, 90, method="higher"))
        line("soft tissue: median abs DOF error (deg)", f"{med:.3f}", f"<= {TARGET_SOFT_MEDIAN}",
             med <= TARGET_SOFT_MEDIAN, med / TARGET_SOFT_MEDIAN)
        line("soft tissue: 90th percentile (deg)", f"{p90:.3f}", f"<= {TARGET_SOFT_P90}",
             p90 <= TARGET_SOFT_P90, p90 / TARGET_SOFT_P90)
    if reference is not None:
        for what, postures in (("labelled IK from the truth", data.truth), ("fit from labelled IK", fitted)):
            gaps = np.nan_to_num(np.abs(angle_errors(model, postures, reference)[:, rot]), nan=np.inf)
            line(f"{what}: median / 90th (deg)",
                 f"{np.median(gaps):.2f} / {np.percentile(gaps, 90, method='higher'):.2f}")
    # The rate target is judged on CPU time: one core's work, whatever else the machine runs.
    rate_target: tuple = ("", None, None)
    if subject.name == "hexapod" and len(subject.rig.views) == 6:
        rate_target = target(f">= {TARGET_HEXAPOD_RATE:.0f}", rate_cpu >= TARGET_HEXAPOD_RATE,
                             rate_cpu / TARGET_HEXAPOD_RATE)
    line("fit images/s per second of CPU (one core)", f"{rate_cpu:.3f}", *rate_target)
    line("fit images/s, wall clock", f"{rate_wall:.3f}")
    line("detection images/s, wall (all views)", f"{n / data.detect_seconds:.1f}")
    counts = {s.value: sum(x is s for x in statuses) for s in Status}
    print(f"  status: {', '.join(f'{k} {v}' for k, v in counts.items())}; "
          f"ambiguous (from {source}): {ambiguous}")
    print(f"  fit took {timing['wall']:.1f} s wall, {timing['cpu']:.1f} s CPU; per image: {csv_path}")


def run(name: str, args: argparse.Namespace) -> None:
    cameras = camera_choice(name, args.cameras)
    subject = load(name, cameras)
    if args.fps:
        subject = replace(subject, fps=args.fps)
    label = (name + (f" ({cameras} cameras)" if cameras else "")
             + (f" at {args.fps:g} Hz" if args.fps else "")
             + (" + soft tissue" if args.soft_tissue else "")
             + (f" + {subject.model.markers[lost_marker(subject.model)].name} lost" if args.lost_claw else "")
             + (f" + model off {100 * args.model_error:g} %" if args.model_error else "")
             + (f" + rig off {args.rig_error:g} px" if args.rig_error else "")
             + (f" + {args.glints} glints per view" if args.glints else ""))
    if args.beyond:
        subject = cut_at_edge(subject, subject.trajectory(args.images, np.random.default_rng(args.seed)),
                              args.beyond)
        label += f" + {100 * args.beyond:g} % beyond the frames' edge"
    rng = np.random.default_rng(args.seed)
    data = render_and_detect(subject, args.images, soft=args.soft_tissue, ghosts=args.ghosts,
                             rng=rng, occlusion=args.occlusion, everywhere=args.everywhere,
                             detector=args.detector, marker_px=args.marker_px, lost_claw=args.lost_claw,
                             glints=args.glints, hidden_run_s=args.hidden_run)
    if data.hidden is not None:
        h = data.hidden
        print(f"\n{label}: hidden {int(h.sum())} of {h.size} marker projections "
              f"({100 * h.mean():.1f} %); images with a marker hidden in some view: "
              f"{int(h.any(axis=(1, 2)).sum())} of {len(h)}; mean hidden run "
              f"{h.sum() / max(1, _run_starts(h)):.1f} images")
    measured = as_measured(subject, args)
    result, timing = fit(measured, data, seed=args.seed, jobs=args.jobs)
    reference = (labelled_postures(measured.model, data.markers, data.truth)
                 if args.soft_tissue or args.model_error else None)
    tag = (name + (f"-{cameras}cams" if cameras else "") + ("-soft" if args.soft_tissue else "")
           + (f"-occ{round(100 * args.occlusion)}" + ("all" if args.everywhere else "")
              + (f"-run{args.hidden_run:g}" if args.hidden_run != OCCLUSION_RUN_S else "") if args.occlusion
              else "")
           + (f"-{args.fps:g}hz" if args.fps else "")
           + (f"-model{100 * args.model_error:g}" if args.model_error else "")
           + (f"-rig{args.rig_error:g}" if args.rig_error else "")
           + (f"-marker{args.marker_px:g}" if args.marker_px != MARKER_DIAMETER_PX else "")
           + ("-lostclaw" if args.lost_claw else "")
           + (f"-glints{args.glints}" if args.glints else "")
           + (f"-beyond{round(100 * args.beyond)}" if args.beyond else ""))
    OUT.mkdir(parents=True, exist_ok=True)
    csv_path = OUT / f"animals-{tag}.csv"
    write_angles_csv(csv_path, subject.model, result.fits, SampleClock(subject.fps))
    report(subject, label, data, result, timing, csv_path, soft=args.soft_tissue, reference=reference)


def cut_at_edge(subject: Subject, truth: np.ndarray, share: float) -> Subject:
    """``subject`` with every view's roi ending at the column (a whole pixel) beyond which
    the share ``share`` of its markers' projections over the movement ``truth`` (T, D) lies,
    inside the view's own roi where it has one: an animal that walks out of the frame. It
    moves as ``subject`` does (a movement kept inside the rois would not leave them)."""
    projected = subject.rig.project(subject.model.marker_positions(truth))  # (T, V, M, 2)
    views = []
    for v, view in enumerate(subject.rig.views):
        x, y, w, h = view.roi or (0, 0, *subject.size_of(view.video))
        edge = int(np.quantile(projected[:, v, :, 0], 1.0 - share))
        views.append(replace(view, roi=(x, y, min(w, max(1, edge - x)), h)))

    def movement(_: Subject, n: int, rng: np.random.Generator) -> np.ndarray:
        return subject.trajectory(n, rng)

    return replace(subject, rig=Rig(tuple(views)), movement=movement)


def as_measured(subject: Subject, args: argparse.Namespace) -> Subject:
    """The subject as the lab that fits it knows it: its model and rig off by
    ``--model-error`` and ``--rig-error`` (drawn from their own generator, so that the images
    are those of a run without them)."""
    rng = np.random.default_rng([args.seed, 1])
    model = measured_model(subject.model, args.model_error, rng) if args.model_error else subject.model
    rig = calibrated_rig(subject.rig, args.rig_error, rng) if args.rig_error else subject.rig
    return replace(subject, model=model, rig=rig)


def _run_starts(hidden: np.ndarray) -> int:
    """The number of hidden runs in a (T, V, M) mask (a run cut by the clip's start counts)."""
    return int(hidden[0].sum() + (hidden[1:] & ~hidden[:-1]).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subject", choices=(*NAMES, "all"), default="all")
    parser.add_argument("--images", type=int, default=20,
                        help="images per subject (the engine of 2026-11-23 fits ~0.05 hexapod images/s)")
    parser.add_argument("--cameras", type=int, choices=(6, 4, 3, 2), default=None,
                        help="fly cameras (hexapod, freefly: default 6), rat cameras (default 3) or "
                             "spider cameras (default 4)")
    parser.add_argument("--soft-tissue", action="store_true",
                        help="skin markers slide 2 px RMS; unmodelled markers in every view")
    parser.add_argument("--ghosts", type=int, default=None,
                        help="ghost blobs per view and image (default 2, or 0 with --soft-tissue: "
                             "the issue's two conditions)")
    parser.add_argument("--occlusion", type=float, default=0.0, metavar="F",
                        help="fraction of marker projections hidden, in runs of "
                             f"{OCCLUSION_RUN_S:g} s per view and marker (default 0)")
    parser.add_argument("--hidden-run", type=float, default=OCCLUSION_RUN_S, metavar="S",
                        help="with --occlusion, the mean length of a hidden run, seconds "
                             f"(default {OCCLUSION_RUN_S:g}: a leg passing; 0.3: a limb behind the body)")
    parser.add_argument("--everywhere", action="store_true",
                        help="with --occlusion, hide each marker from every view at once")
    parser.add_argument("--glints", type=int, default=0, metavar="N",
                        help="reflections off the animal's body per view and image, on its segments "
                             "(default 0)")
    parser.add_argument("--beyond", type=float, default=0.0, metavar="F",
                        help="the share of each view's marker projections beyond its frame's edge "
                             "(a roi; default 0)")
    parser.add_argument("--lost-claw", action="store_true",
                        help="the first branch's last marker (a claw, a toe) is missing from every image")
    parser.add_argument("--fps", type=float, default=None,
                        help="frame rate of the movement (default: the subject's own, 50-250 Hz)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1, help="processes fitting chunks")
    parser.add_argument("--model-error", type=float, default=0.0, metavar="F",
                        help="fit with segment lengths and marker placements off by a relative "
                             "N(0, F), e.g. 0.05 (default 0)")
    parser.add_argument("--rig-error", type=float, default=0.0, metavar="PX",
                        help="fit with every view's image shifted by PX pixels (default 0)")
    parser.add_argument("--marker-px", type=float, default=MARKER_DIAMETER_PX, metavar="D",
                        help=f"markers' imaged diameter, pixels (default {MARKER_DIAMETER_PX:g}, the "
                        "issue's; bigger markers fuse more often)")
    parser.add_argument("--threshold", default=None,
                        help="detection threshold: a grey level, 'otsu' or 'auto' (default: mocap fit's)")
    args = parser.parse_args()
    try:
        args.detector = (DetectorParams() if args.threshold is None else
                         DetectorParams(threshold=args.threshold if args.threshold in ("otsu", "auto")
                                        else float(args.threshold)))
    except ValueError as exc:
        parser.error(f"--threshold: {exc}")
    if args.ghosts is None:
        args.ghosts = 0 if args.soft_tissue else 2
    if (args.images < 1 or args.jobs < 1 or min(args.ghosts, args.glints) < 0
            or not 0 <= args.occlusion <= 0.5 or not 0 <= args.beyond <= 0.5
            or (args.fps is not None and args.fps <= 0) or not 0 < args.hidden_run <= 10
            or not (0 <= args.model_error <= 0.5 and 0 <= args.rig_error <= 50)):
        parser.error("--images and --jobs must be >= 1, --ghosts and --glints >= 0, --occlusion and "
                     "--beyond in [0, 0.5], --fps > 0, --hidden-run in (0, 10], --model-error in [0, 0.5], "
                     "--rig-error in [0, 50]")
    names = NAMES if args.subject == "all" else (args.subject,)
    print(f"bench/animals.py: seed {args.seed}, {args.images} images per subject, "
          f"{args.marker_px:g} px markers, {args.ghosts} ghost blobs per view"
          + (f", soft tissue {SOFT_TISSUE_PX:g} px RMS + unmodelled markers" if args.soft_tissue else "")
          + (f", {100 * args.occlusion:g} % of marker projections hidden"
             + (" (each marker from every view at once)" if args.everywhere else "")
             + f" in runs of {args.hidden_run:g} s"
             if args.occlusion else "")
          + (f", model off {100 * args.model_error:g} %" if args.model_error else "")
          + (f", rig off {args.rig_error:g} px" if args.rig_error else "")
          + (f", {args.glints} glints per view on the body" if args.glints else "")
          + (f", {100 * args.beyond:g} % of marker projections beyond the frames' edge"
             if args.beyond else "")
          + f", threshold {args.detector.threshold}")
    for name in names:
        run(name, args)


if __name__ == "__main__":
    main()
