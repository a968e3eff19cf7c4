"""The ``mocap`` command line.

Errors a user can make (bad files, bad options) end with exit code 2 and one
line on stderr saying what is wrong.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
import typer
from rich.progress import Progress
from typer.exceptions import TyperException

from cli.options import (
    detector_options,
    detector_parameters,
    fit_options,
    fit_parameters,
    flags_in_errors,
    with_options,
)
from core.benchmark import FUSION_PX, locust_benchmark
from core.bounds import bounds_of
from core.cost import check_fit_cost, estimate_fit_cost
from core.export import EXPORTS, unit_scale
from core.fit import FitParams, ImageFit, Status
from core.histogram import HistogramError, Histograms
from core.model import KinematicModel, ModelError
from core.options import FitOptions, build_fit
from core.overlay import OVERLAY_DIR, job_from_report, overlay_job
from core.pipeline import FitJob, run_fit, write_outputs
from core.plots import PLOTS_DIR, write_plots
from core.preview import preview_frame
from core.results import read_angles_csv
from core.rig import Rig, RigError
from core.sequence import fit_sequence
from core.synth import natural_movements, read_truth_csv, render_frames, write_truth_csv, write_video
from core.video import VideoError, VideoSet
from core.warmup import compile_kernels_saying_so

PRIOR_WEIGHT = bounds_of(FitOptions)["prior_weight"]

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__.splitlines()[0])

USER_ERRORS: tuple[type[Exception], ...] = (
    ModelError, RigError, HistogramError, VideoError, ValueError, OSError)


def run() -> None:
    """Console entry point: typer's usage errors also become one line and exit code 2."""
    try:
        code = app(standalone_mode=False)  # returns the code of a typer.Exit raised inside
    except TyperException as exc:
        typer.echo(f"mocap: error: {exc.format_message()}", err=True)
        sys.exit(exc.exit_code)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("mocap: aborted", err=True)
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)


@contextmanager
def user_errors(*also: type[Exception]) -> Iterator[None]:
    """Turn a user's mistake (or one of the exception types ``also``) into one line on stderr and
    exit code 2."""
    try:
        yield
    except (*USER_ERRORS, *also) as exc:
        typer.echo(f"mocap: error: {exc}", err=True)
        raise typer.Exit(2) from None


@app.callback()
def main() -> None:
    """Model-based motion capture by Simulated Annealing (Zakotnik et al. 2004)."""


@app.command()
def demo(
    samples: Annotated[int, typer.Option(min=1, max=5000, help="images to render and fit")] = 200,
    seed: Annotated[int, typer.Option(help="seed of the movement, the rendering and the fit")] = 2004,
) -> None:
    """Render the locust hind-leg example, detect its markers, fit it and print the accuracy."""
    compile_kernels_saying_so(lambda line: print(line, flush=True))
    t0 = time.perf_counter()
    bench = locust_benchmark(seed, samples)
    print(f"rendered and detected {samples} images of the locust hind leg "
          f"(two views, 4 px markers) in {time.perf_counter() - t0:.1f} s")
    t0 = time.perf_counter()
    result = fit_sequence(bench.detections, model=bench.model, rig=bench.rig,
                          histograms=Histograms.uniform(bench.model),
                          params=FitParams(fusion_px=FUSION_PX), seed=seed)
    seconds = time.perf_counter() - t0
    fitted = np.array([f.dofs for f in result.fits])
    rmse = np.sqrt(np.nanmean((fitted - bench.truth) ** 2, axis=0))
    errors = np.array([f.error for f in result.fits])
    print(f"fitted {samples} images in {seconds:.1f} s ({samples / seconds:.0f} images/s, one process)")
    print("RMSE against the truth (degrees): " + ", ".join(
        f"{name} {value:.3f}" for name, value in zip(bench.model.dof_names, rmse, strict=True)))
    print(f"mean view error {np.nanmean(errors):.3f} px (Eq. 5, 8 markers); "
          f"{sum(f.status is not Status.OK for f in result.fits)} images not ok")


Opt = typer.Option


@app.command()
@with_options(fit_parameters)
def fit(
    videos: Annotated[list[Path], typer.Argument(help="video file(s), one per camera of the rig")],
    model: Annotated[Path, Opt("--model", help="model.xml (FORMATS §1)")],
    rig: Annotated[Path, Opt("--rig", help="rig.json (FORMATS §2)")],
    out: Annotated[Path, Opt("--out", help="output directory")],
    histograms: Annotated[Path | None, Opt("--histograms", help="starting histograms.xml "
                                           "(default: uniform, --prior-weight counts)")] = None,
    jobs: Annotated[int, Opt(min=1, max=256, help="processes fitting chunks in parallel, one core each")] = 1,
    export: Annotated[str | None, Opt(help="also write some of mot,trc,c3d,detections "
                                      "(docs/INTERCHANGE.md)")] = None,
    export_units: Annotated[str, Opt(help="trc/c3d positions, mot translations: model or m")] = "model",
    # ---- seeing the fit (core.overlay, core.plots; docs/SEEING_THE_FIT.md) ----
    overlay: Annotated[bool, Opt("--overlay", help="then draw the fit over the videos: OUT/overlay")] = False,
    plots: Annotated[bool, Opt("--plots", help="then plot angles and histograms: OUT/plots/")] = False,
    **options: Any,
) -> None:
    """Detect markers in VIDEO(s) and fit the model to every image: angles, histograms, report.

    The options after --plots are the fit's (core.options.FitOptions, as the API's JobOptions).
    """
    with user_errors():
        exports = _export_kinds(export, EXPORTS)
        fit_opts = fit_options(options)
        kinematic = KinematicModel.from_xml(model)
        if exports:
            unit_scale(kinematic, export_units)
        camera_rig = Rig.from_json(rig)
        start = None if histograms is None else Histograms.from_xml(histograms, kinematic)
        # Per image, before any video is decoded: the fusion distance does not change the cost.
        check_fit_cost(estimate_fit_cost(kinematic, camera_rig, fit_opts.fit_params(0.0), images=1))
        warn_undetermined(model, kinematic)
        with flags_in_errors():
            built = build_fit(fit_opts, kinematic, camera_rig, videos, start)
        job = built.job
        with progress_bar(len(job.source)) as advance:
            outcome = run_fit(job, built.start, jobs=jobs, progress=advance)
        report = write_outputs(out, job, outcome)
        exported = _export_fit(out, exports, export_units, job)
    print(f"{report['images']} images in {report['seconds']} s ({report['images_per_s']} images/s); "
          f"status {report['status']}; mean error {report['error_px']['mean']} px; "
          f"wrote {out}/angles.csv, histograms.xml, report.json{exported}")
    warn_few_detections(report, len(kinematic.markers))
    warn_advice(report)
    with user_errors():
        if overlay:
            _draw_overlay(job, out, OVERLAY_WORST)
        if plots:
            _draw_plots(out, kinematic, built.start, outcome.result.histograms)


FEW_BLOBS_SHARE = 0.25  # of the model's markers: fewer blobs per image in a view earn a warning


def warn_undetermined(path: Path, model: KinematicModel) -> None:
    """One line on stderr when the model's markers cannot determine some DOF in any posture
    (``core.identifiability``): the fit goes on, each image then has an alternative."""
    advice = model.identifiability.advice()
    if advice:
        typer.echo(f"mocap: warning: {path}: {advice}", err=True)


def warn_few_detections(report: dict[str, Any], n_markers: int) -> None:
    """One line on stderr per view whose images had on average fewer blobs than
    :data:`FEW_BLOBS_SHARE` of the model's ``n_markers`` (``report``: ``report.json``'s
    content): the detector's settings, not the animal, are then the likely cause. A
    background brighter than the threshold is one region larger than the largest marker
    and dropped; markers dimmer than it (motion blur) are not found."""
    detector = report["settings"]["detector"]
    for view, counts in report["detections_per_view"].items():
        if counts["mean"] is not None and counts["mean"] < FEW_BLOBS_SHARE * n_markers:
            typer.echo(f"mocap: warning: view {view!r} has {counts['mean']:g} blobs per image on "
                       f"average for the model's {n_markers} markers: check --threshold "
                       f"({detector['threshold']}; a grey level, 'otsu' or 'auto') and "
                       f"--max-area ({detector['max_area']}) on a few frames with `mocap detect`",
                       err=True)


def warn_advice(report: dict[str, Any]) -> None:
    """``report.json``'s ``advice`` (``core.pipeline``: most images over the threshold, or
    else ambiguous), a line each on stderr, with where to see the images."""
    for line in report["advice"]:
        typer.echo(f"mocap: warning: {line} (--overlay; docs/SEEING_THE_FIT.md)", err=True)


@contextmanager
def progress_bar(total: int) -> Iterator[Callable[[ImageFit], None] | None]:
    """A progress callback: a bar on a terminal, nothing otherwise."""
    if not sys.stderr.isatty():
        yield None
        return
    with Progress(transient=True) as bar:
        task = bar.add_task("fitting", total=total)
        yield lambda _fit: bar.advance(task)


@app.command()
def synth(
    model: Annotated[Path, Opt("--model", help="model.xml")],
    rig: Annotated[Path, Opt("--rig", help="rig.json")],
    out: Annotated[Path, Opt("--out", help="output directory")],
    trajectory: Annotated[Path | None, Opt(help="truth CSV to render (default: generated)")] = None,
    samples: Annotated[int, Opt(min=1, help="images to generate without --trajectory")] = 300,
    fps: Annotated[float, Opt(min=0.001, help="frames per second of the video")] = 50.0,
    marker_diameter_px: Annotated[float, Opt(min=0.5)] = 4.0,
    noise: Annotated[float, Opt(min=0.0, help="background noise sigma, grey levels")] = 2.0,
    ghosts: Annotated[int, Opt(min=0, help="ghost markers per view and image")] = 0,
    interlaced: Annotated[bool, Opt(help="two fields per frame (samples are fields)")] = False,
    seed: Annotated[int, Opt()] = 0,
) -> None:
    """Render a model moving through a rig: DIR/video<k>.avi per camera and DIR/truth.csv."""
    with user_errors():
        kinematic, camera_rig = KinematicModel.from_xml(model), Rig.from_json(rig)
        rng = np.random.default_rng(seed)
        if trajectory is not None:
            names, truth = read_truth_csv(trajectory)
            if names != kinematic.dof_names:
                raise ValueError(f"{trajectory} has DOF columns {names}, the model {kinematic.dof_names}")
        else:
            truth = natural_movements(kinematic, camera_rig, samples, rng=rng, fps=fps)
        if interlaced and len(truth) % 2:
            truth = truth[:-1]
        out.mkdir(parents=True, exist_ok=True)
        for k in range(camera_rig.n_videos):
            frames = render_frames(kinematic, camera_rig, truth, rng=rng, video=k,
                                   marker_diameter_px=marker_diameter_px, noise_sigma=noise,
                                   ghosts_per_view=ghosts, interlaced=interlaced)
            write_video(out / f"video{k}.avi", frames, fps=fps)
        write_truth_csv(out / "truth.csv", kinematic, truth, fps=fps, interlaced=interlaced)
    print(f"wrote {camera_rig.n_videos} video(s) and truth.csv ({len(truth)} images) to {out}")


# ---- mocap rig import: other tools' calibrations as rig.json (core/calibration.py) ------------

rig_app = typer.Typer(no_args_is_help=True, help="Camera rigs (FORMATS §2).")
app.add_typer(rig_app, name="rig")


@rig_app.command("import")
def rig_import(
    fmt: Annotated[str, typer.Argument(metavar="FORMAT", help="anipose, opencv or dlt")],
    files: Annotated[list[Path], typer.Argument(help="calibration file(s); opencv takes one per camera")],
    out: Annotated[Path, Opt("--out", help="rig.json to write")],
    video_index: Annotated[
        str | None, Opt(help="video index of each view, e.g. '0,1,1' (default: 0, 1, 2 …)")] = None,
    height: Annotated[
        str | None, Opt(help="dlt: image height in pixels, one for all cameras or 'h1,h2,…'")] = None,
) -> None:
    """Convert a calibration of Anipose, OpenCV or DLTdv/Argus into rig.json (docs/INTERCHANGE.md)."""
    from core.calibration import import_rig

    with user_errors():
        videos = None if video_index is None else [int(x) for x in _numbers(video_index, "--video-index")]
        heights = None if height is None else _numbers(height, "--height")
        rig_out = import_rig(fmt, files, heights=heights, videos=videos)
        out.write_text(rig_out.to_json())
    print(f"wrote {out}: {len(rig_out.views)} view(s) "
          f"({', '.join(v.name for v in rig_out.views)}) for {rig_out.n_videos} video(s)")


def _numbers(text: str, option: str) -> list[float]:
    """'1,2,3' → [1.0, 2.0, 3.0]; whole numbers for --video-index."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"{option} must be comma-separated numbers, got {text!r}") from None
    if option == "--video-index" and not all(v.is_integer() and v >= 0 for v in values):
        raise ValueError(f"{option} must be whole numbers >= 0, got {text!r}")
    return values


# ---- exports for other tools: mocap export, mocap fit --export (core/export.py) ---------------


@app.command("export")
def export_results(
    angles: Annotated[Path, typer.Argument(help="angles.csv of mocap fit (FORMATS §3)")],
    model: Annotated[Path, Opt("--model", help="the model.xml it was fitted with")],
    out: Annotated[Path, Opt("--out", help="output directory")],
    to: Annotated[str, Opt("--to", help="some of mot,trc,c3d")] = "mot,trc,c3d",
    units: Annotated[str, Opt(help="trc/c3d positions, mot translations: model or m")] = "model",
) -> None:
    """Write fitted angles as OpenSim .mot and marker trajectories as .trc and .c3d."""
    from core.export import export
    from core.results import read_angles_csv

    with user_errors():
        kinds = _export_kinds(to, ("mot", "trc", "c3d"))
        kinematic = KinematicModel.from_xml(model)
        table = read_angles_csv(angles)
        out.mkdir(parents=True, exist_ok=True)
        paths = export(out, kinds, table, kinematic, units=units)
    print(f"wrote {', '.join(str(p) for p in paths)}")


def _export_kinds(text: str | None, allowed: tuple[str, ...]) -> list[str]:
    """--export 'mot,trc' → ['mot', 'trc'], checked before any work is done."""
    if text is None:
        return []
    kinds = [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in allowed]
    if unknown or not kinds:
        raise ValueError(f"exports must be some of {','.join(allowed)}, got {text!r}")
    return kinds


def _export_fit(out: Path, kinds: list[str], units: str, job: FitJob) -> str:
    """The exports asked of ``mocap fit``, from the angles.csv just written; detections.csv
    decodes and detects the videos once more. Returns ', name, …' for the summary line."""
    from core.export import DETECTIONS_FILE, export, write_detections_csv
    from core.results import read_angles_csv

    if not kinds:
        return ""
    table = read_angles_csv(out / "angles.csv")
    paths = export(out, [k for k in kinds if k != "detections"], table, job.model, units=units)
    if "detections" in kinds:
        source = job.source
        write_detections_csv(out / DETECTIONS_FILE, source[0:len(source)], source.rig, job.clock)
        paths.append(out / DETECTIONS_FILE)
    return "".join(f", {p.name}" for p in paths)
# ---- seeing the fit: `overlay`, `plots`, `detect` (core.overlay, core.plots, core.preview;
# docs/SEEING_THE_FIT.md) ------------------------------------------------------------------

OVERLAY_WORST = 12  # images of the largest errors on the contact sheet (and every ambiguous one)


@app.command()
def overlay(
    results: Annotated[Path, typer.Argument(help="a results directory of `mocap fit` (or a job's archive)")],
    videos: Annotated[list[Path], typer.Argument(help="the video file(s) it was fitted from")],
    model: Annotated[Path | None, Opt("--model", help="model.xml (default: RESULTS/model.xml)")] = None,
    rig: Annotated[Path | None, Opt("--rig", help="rig.json (default: RESULTS/rig.json)")] = None,
    worst: Annotated[int, Opt(min=0, max=1000, help="images of the largest errors to show")] = OVERLAY_WORST,
) -> None:
    """Draw a computed fit over its videos: RESULTS/overlay/ (videos, worst images, contact sheet)."""
    with user_errors():
        kinematic = KinematicModel.from_xml(_in_results(model, results, "model.xml", "--model"))
        camera_rig = Rig.from_json(_in_results(rig, results, "rig.json", "--rig"))
        report = _report(_in_results(None, results, "report.json", ""))
        job = job_from_report(report, videos, model=kinematic, rig=camera_rig)
        _draw_overlay(job, results, worst)


@app.command()
def plots(
    results: Annotated[Path, typer.Argument(help="a results directory of `mocap fit` (or a job's archive)")],
    model: Annotated[Path | None, Opt("--model", help="model.xml (default: RESULTS/model.xml)")] = None,
    histograms: Annotated[Path | None, Opt("--histograms", help="the fit's starting histograms.xml "
                                           "(default: uniform, --prior-weight counts)")] = None,
    prior_weight: Annotated[float, Opt(help=PRIOR_WEIGHT.help)] = FitOptions.prior_weight,
) -> None:
    """Plot a computed fit: RESULTS/plots/angles.{png,svg} and histograms.{png,svg}."""
    with user_errors():
        kinematic = KinematicModel.from_xml(_in_results(model, results, "model.xml", "--model"))
        start = (Histograms.from_xml(histograms, kinematic) if histograms is not None
                 else _uniform_prior(kinematic, prior_weight))
        final = Histograms.from_xml(_in_results(None, results, "histograms.xml", ""), kinematic)
        _draw_plots(results, kinematic, start, final)


@app.command()
@with_options(detector_parameters)
def detect(
    videos: Annotated[list[Path], typer.Argument(help="video file(s), one per camera of the rig")],
    rig: Annotated[Path, Opt("--rig", help="rig.json (FORMATS §2)")],
    out: Annotated[Path, Opt("--out", help="output directory for the preview images")],
    frames: Annotated[str, Opt(help="frame indices, comma-separated")] = "0",
    **options: Any,
) -> None:
    """Preview detection on a few frames: each view's roi, thresholded mask and centroids; counts."""
    with user_errors():
        camera_rig = Rig.from_json(rig)
        detector = detector_options(options)
        indices = _frame_indices(frames)
        video_set = VideoSet(videos)
        camera_rig.check_videos([(i.width, i.height) for i in video_set.infos])
        if indices[-1] >= video_set.frames:
            raise ValueError(f"--frames: frame {indices[-1]} is past the videos' {video_set.frames} frames")
        out.mkdir(parents=True, exist_ok=True)
        counts, levels = {}, {}
        names = [v.name for v in camera_rig.views]
        for index in indices:
            (decoded,) = video_set.read(index, index + 1)
            drawn, found, thresholds = preview_frame(decoded, rig=camera_rig, params=detector)
            for k, image in enumerate(drawn):
                cv2.imwrite(str(out / f"frame_{index:06d}_video{k}.png"), image)
            counts[index] = dict(zip(names, map(int, found.counts), strict=True))
            levels[index] = dict(zip(names, thresholds, strict=True))
            print(f"frame {index}: " + ", ".join(
                f"{name} {counts[index][name]} (threshold {levels[index][name]:g})" for name in names))
        (out / "counts.json").write_text(json.dumps({"detector": asdict(detector), "counts": counts,
                                                     "thresholds": levels}, indent=2) + "\n")
    print(f"wrote {len(indices) * camera_rig.n_videos} image(s) and counts.json to {out}")


def _uniform_prior(model: KinematicModel, prior_weight: float) -> Histograms:
    with flags_in_errors():
        return FitOptions(prior_weight=prior_weight).uniform_prior(model)


def _draw_overlay(job: FitJob, results: Path, worst: int) -> None:
    manifest = overlay_job(job, results, worst=worst)
    print(f"wrote {results / OVERLAY_DIR}: {', '.join(manifest['videos'])}, "
          f"{len(manifest['images'])} image(s), {manifest['contact_sheet'] or 'no contact sheet'}")


def _draw_plots(results: Path, model: KinematicModel, start: Histograms, final: Histograms) -> None:
    table = read_angles_csv(results / "angles.csv")
    names = write_plots(results / PLOTS_DIR, table, model, start, final)
    print(f"wrote {results / PLOTS_DIR}: {', '.join(names)}")


def _report(path: Path) -> dict[str, Any]:
    try:
        report = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not a report.json of mocap fit: {exc}") from None
    if not isinstance(report, dict):
        raise ValueError(f"{path} is not a report.json of mocap fit: not a JSON object")
    return report


def _in_results(given: Path | None, results: Path, name: str, option: str) -> Path:
    """``given``, else RESULTS/name; an error naming the option when neither exists."""
    if given is not None:
        return given
    if not results.is_dir():
        raise ValueError(f"{results} is not a directory of results")
    path = results / name
    if not path.is_file():
        hint = f": give it with {option}" if option else " (not a results directory of mocap fit?)"
        raise ValueError(f"{results} has no {name}{hint}")
    return path


def _frame_indices(text: str) -> list[int]:
    """--frames: '0,100,200' → sorted distinct indices >= 0."""
    try:
        indices = sorted({int(x) for x in text.split(",")})
    except ValueError:
        raise ValueError(f"--frames must be frame indices separated by commas, got {text!r}") from None
    if not indices or indices[0] < 0 or len(indices) > MAX_PREVIEW_FRAMES:
        raise ValueError(f"--frames must hold 1 to {MAX_PREVIEW_FRAMES} indices >= 0, got {text!r}")
    return indices


MAX_PREVIEW_FRAMES = 100
