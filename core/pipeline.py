"""From video files to fitted angles: a video job, its plan, its run and its result files.

A :class:`VideoSource` is a lazy sequence of per-image detections: slicing it
decodes and detects only that range of frames (seeking into the video), and
indexing it decodes one frame, so memory is bounded by one frame whatever the
video's length, and a chunk can start in the middle of a long video. With
de-interlacing every frame gives two images (its fields, in time order).

A :class:`FitJob` is everything that decides a result. ``mocap fit`` and the service's
workers run it with the same steps (``core.sequence``) and these two ends:

- :func:`plan`: the number of images, the chunks (``core.sequence.plan_chunks``), and the
  root-tracking offsets (tracking is sequential, so it runs once over the whole sequence);
- :func:`outputs`: the contents of ``angles.csv``, ``histograms.xml`` and ``report.json``
  (:func:`write_outputs` writes them into a directory, the workers into their storage).

:func:`run_fit` runs a job in this process or a pool of processes (``core.sequence.fit_sequence``).
"""

from __future__ import annotations

import gc
import io
import json
import math
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any, overload

import numpy as np

from core.detect import DetectorParams, detect, marker_diameter, restored_at_edges
from core.error import Detections
from core.fields import detect_fields, field_parities, field_rig
from core.fit import FitParams, ImageFit, Status
from core.histogram import Histograms
from core.model import KinematicModel
from core.results import SampleClock, write_angles_csv
from core.rig import Rig
from core.sequence import SequenceResult, fit_sequence, plan_chunks
from core.track import RootTracking, root_reference, track_root
from core.video import VideoSet

__all__ = [
    "OUTPUT_FILES", "FitJob", "FitOutcome", "Outputs", "Plan", "VideoSource", "ambiguous_advice",
    "ambiguous_dofs", "build_report",
    "estimate_marker_diameter", "outputs", "over_threshold_advice", "plan", "run_fit",
    "write_outputs",
]


@dataclass(frozen=True)
class VideoSource(Sequence[Detections]):
    """Detections of every analysed image of a set of synchronised videos, decoded on demand.

    videos : one file per camera, in the rig's ``video`` index order.
    deinterlace : every frame gives two images, its fields in ``field_order`` (``core.fields``).
    marker_px : the markers' diameter in pixels: a blob a view's edge cuts is moved to its
        marker's centre (``core.detect.restored_at_edges``); 0: blobs as detected.
    """

    videos: tuple[Path, ...]
    rig: Rig
    detector: DetectorParams = field(default_factory=DetectorParams)
    deinterlace: bool = False
    field_order: str = "even-first"
    marker_px: float = 0.0

    def __post_init__(self) -> None:
        field_parities(self.field_order)

    @cached_property
    def _field_rigs(self) -> tuple[Rig, Rig]:
        return field_rig(self.rig, 0), field_rig(self.rig, 1)

    @cached_property
    def _videos(self) -> VideoSet:
        """The probed videos, once: chunks and re-analyses seek without probing again.

        Checked against the rig here, so that a missing video or a roi outside the
        frame fails the job before any frame is fitted.
        """
        videos = VideoSet(self.videos)
        self.rig.check_videos([(info.width, info.height) for info in videos.infos])
        return videos

    @cached_property
    def framed_rig(self) -> Rig:
        """:attr:`rig` filming these videos (``Rig.framed``): what the fit reads, so that a
        marker out of a frame is charged as one its camera could not see."""
        return self.rig.framed([(info.width, info.height) for info in self._videos.infos])

    @property
    def fps(self) -> float:
        return self._videos.fps

    @property
    def per_frame(self) -> int:
        return 2 if self.deinterlace else 1

    def __len__(self) -> int:
        return self._videos.frames * self.per_frame

    @overload
    def __getitem__(self, index: int) -> Detections: ...

    @overload
    def __getitem__(self, index: slice) -> Iterator[Detections]: ...  # type: ignore[override]

    def __getitem__(self, index):
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            if step != 1:
                raise ValueError("a VideoSource can only be sliced contiguously")
            return self._range(start, stop)
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"image {index} out of range for {n} images")
        return next(self._range(index % n, index % n + 1))

    def decoded(
        self, first: int, last: int
    ) -> Iterator[tuple[tuple[np.ndarray, ...], tuple[Detections, ...]]]:
        """Frames ``[first, last)`` with the detections of their images, in one decoding pass:
        per frame, one BGR uint8 (H, W, 3) frame per video and :attr:`per_frame` Detections
        (its fields in time order when de-interlacing). Overlays draw on these."""
        for frames in self._videos.read(first, last):
            images = (
                detect_fields(frames, rig=self.rig, params=self.detector,
                              field_order=self.field_order, rigs=self._field_rigs)
                if self.deinterlace
                else (detect(frames, rig=self.rig, params=self.detector),)
            )
            yield frames, tuple(restored_at_edges(det, self.framed_rig, self.marker_px) for det in images)

    def restoring(self, marker_px: float) -> VideoSource:
        """This source with :attr:`marker_px` set; the videos it has probed are not probed
        again (each probe decodes the end of every video)."""
        source = replace(self, marker_px=float(marker_px))
        for name in ("_field_rigs", "_videos", "framed_rig"):
            if name in self.__dict__:
                source.__dict__[name] = self.__dict__[name]
        return source

    def _range(self, start: int, stop: int) -> Iterator[Detections]:
        """Detections of images [start, stop), decoding frames in one pass."""
        k = self.per_frame
        first, last = start // k, (stop + k - 1) // k
        sample = first * k
        for _, images in self.decoded(first, last):
            for det in images:
                if start <= sample < stop:
                    yield det
                sample += 1


def estimate_marker_diameter(source: VideoSource, *, images: int = 50) -> float | None:
    """The markers' diameter in pixels (``core.detect.marker_diameter``) over the first
    ``images`` images, or None when none of them has a detection.

    The first images, in one decoding pass: spreading them over the video would cost one
    seek each (docs/ENGINE_NOTES.md).
    """
    return marker_diameter(source[0:min(images, len(source))])


@dataclass(frozen=True)
class FitJob:
    """One fitting job: videos, model, rig and every setting that decides the result.

    chunk_size : images per chunk; None fits the sequence as one chunk.
    root : optional root tracking (``core.track``).
    """

    source: VideoSource
    model: KinematicModel
    params: FitParams = field(default_factory=FitParams)
    seed: int = 0
    chunk_size: int | None = None
    root: RootTracking | None = None

    @property
    def clock(self) -> SampleClock:
        return SampleClock(self.source.fps, self.source.deinterlace, self.source.field_order)


@dataclass(frozen=True)
class Plan:
    """What :func:`plan` decided: image count, chunk ranges ``[first, last)``, offsets (N, V, 2)."""

    images: int
    chunks: list[tuple[int, int]]
    offsets: np.ndarray | None


def plan(job: FitJob) -> Plan:
    """Count the images, split them into chunks, and track the root if asked."""
    n = len(job.source)
    offsets = None
    if job.root is not None:
        reference = root_reference(job.model, job.source.rig, job.root.marker)
        offsets = track_root(job.source[0:n], reference=reference, tracking=job.root)
    return Plan(n, plan_chunks(n, job.chunk_size), offsets)


CHUNKS_PER_PROCESS = 4


@dataclass(frozen=True)
class FitOutcome:
    """What :func:`run_fit` measured besides the fits themselves."""

    result: SequenceResult
    seconds: float
    jobs: int


def run_fit(
    job: FitJob,
    histograms: Histograms,
    *,
    jobs: int = 1,
    progress: Callable[[ImageFit], None] | None = None,
) -> FitOutcome:
    """Fit every image of ``job`` in this process, or its chunks in ``jobs`` processes.

    With several processes and no ``job.chunk_size``, the sequence is split into
    :data:`CHUNKS_PER_PROCESS` chunks per process, handed out as processes free
    up (images differ in cost: equal halves leave one process idle, docs/ENGINE_NOTES.md);
    chunks are fitted from ``histograms`` and merged by counts,
    exactly as distributed workers do, and so are the re-analyses. ``progress``
    is then not called: every image is fitted in another process.
    """
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    t0 = time.perf_counter()
    if jobs > 1 and job.chunk_size is None:
        chunks = jobs * CHUNKS_PER_PROCESS
        job = replace(job, chunk_size=max(1, math.ceil(len(job.source) / chunks)))
    steps = plan(job)
    kwargs: dict[str, Any] = dict(
        model=job.model, rig=job.source.framed_rig, histograms=histograms, params=job.params,
        seed=job.seed, chunk_size=job.chunk_size, offsets=steps.offsets,
    )
    if jobs == 1:
        result = fit_sequence(job.source, progress=progress, **kwargs)
    else:
        # The processes fork from this one: a collection in a child walks every inherited
        # object and so copies every page of the heap (copy-on-write). Frozen objects are
        # not walked (docs/ENGINE_NOTES.md, "The pipeline").
        gc.freeze()
        try:
            with ProcessPoolExecutor(max_workers=jobs) as pool:
                result = fit_sequence(job.source, map_chunks=pool.map, **kwargs)
        finally:
            gc.unfreeze()
    return FitOutcome(result, time.perf_counter() - t0, jobs)


OUTPUT_FILES = ("angles.csv", "histograms.xml", "report.json")


@dataclass(frozen=True)
class Outputs:
    """The contents of a fit's result files (FORMATS §3, §4, §5).

    report : a dict until :meth:`files`, so that the service adds what only it knows.
    """

    angles_csv: str
    histograms_xml: str
    report: dict[str, Any]

    def files(self) -> dict[str, str]:
        """Each of :data:`OUTPUT_FILES` and its text."""
        report = json.dumps(self.report, indent=2) + "\n"
        return dict(zip(OUTPUT_FILES, (self.angles_csv, self.histograms_xml, report), strict=True))


def outputs(job: FitJob, outcome: FitOutcome) -> Outputs:
    """``angles.csv``, ``histograms.xml`` and ``report.json`` of a fitted job (:func:`build_report`)."""
    angles = io.StringIO()
    write_angles_csv(angles, job.model, outcome.result.fits, job.clock)
    return Outputs(angles.getvalue(), outcome.result.histograms.to_xml(), build_report(job, outcome))


def write_outputs(out: Path, job: FitJob, outcome: FitOutcome) -> dict[str, Any]:
    """Write :func:`outputs` into the directory ``out`` (made if missing); return the report."""
    out.mkdir(parents=True, exist_ok=True)
    results = outputs(job, outcome)
    for name, text in results.files().items():
        (out / name).write_bytes(text.encode())
    return results.report


def build_report(job: FitJob, outcome: FitOutcome) -> dict[str, Any]:
    """Images, throughput, error statistics (total and per compared marker projection),
    over-threshold and ambiguous images (an alternative posture in angles.csv's
    ``alternative_deg``), the DOFs the model's markers cannot determine in any posture
    (``core.identifiability``), detections and settings."""
    fits = outcome.result.fits
    fitted = [f for f in fits if f.status is not Status.NO_DETECTIONS]
    errors = np.array([f.error for f in fitted])
    n_markers, rotational = len(job.model.markers), job.model.rotational
    per_marker = np.array([f.error_per_marker(n_markers) for f in fitted])
    over = [f.sample for f in fits if f.status is Status.OVER_THRESHOLD]
    ambiguous = [f.sample for f in fitted if math.isfinite(f.alternative_deg(rotational))]
    by_dof = ambiguous_dofs(fitted, job.model)
    counts = np.array([f.detections for f in fits]).reshape(len(fits), -1)
    views = [v.name for v in job.source.rig.views]
    return {
        "images": len(fits),
        "videos": [str(p) for p in job.source.videos],
        "fps": job.clock.fps,
        "deinterlaced": job.source.deinterlace,
        "seconds": round(outcome.seconds, 3),
        "images_per_s": round(len(fits) / outcome.seconds, 2) if outcome.seconds > 0 else None,
        "jobs": outcome.jobs,
        "status": {s.value: sum(f.status is s for f in fits) for s in Status},
        "error_px": _stats(errors),
        "error_per_marker_px": _stats(per_marker),
        "error_threshold_per_marker_px": job.params.error_threshold_px,
        "reanalysed": sum(f.attempts > 1 for f in fits),
        "over_threshold_images": over,
        "ambiguous": len(ambiguous),
        "ambiguous_images": ambiguous,
        "ambiguous_dofs": by_dof,
        "undetermined_dofs": _undetermined(job.model),
        "advice": (over_threshold_advice(len(over), per_marker, job.params.error_threshold_px)
                   or ambiguous_advice(len(ambiguous), len(fitted), by_dof)),
        "detections_per_view": {
            name: {"mean": round(float(counts[:, v].mean()), 3) if len(fits) else None,
                   "min": int(counts[:, v].min()) if len(fits) else None,
                   "per_image": counts[:, v].tolist()}
            for v, name in enumerate(views)
        },
        "settings": {
            "model": job.model.name,
            "seed": job.seed,
            "chunk_size": job.chunk_size,
            "field_order": job.source.field_order if job.source.deinterlace else None,
            "root_tracking": None if job.root is None else asdict(job.root),
            "fit": asdict(job.params),
            "detector": asdict(job.source.detector),
        },
    }


MOST_IMAGES_SHARE = 0.5  # of the fitted images: more over the threshold, or ambiguous, earn advice
ADVISED_DOFS = 3  # the DOFs named in the advice on ambiguous images, most often ambiguous first


def over_threshold_advice(over: int, per_marker: np.ndarray, threshold_px: float) -> list[str]:
    """One line of advice when more than :data:`MOST_IMAGES_SHARE` of the fitted images
    (``per_marker`` (n,), their ``error_per_marker_px``) are over the threshold (``over`` of
    them), else none. Markers off the model in most images are not single bad images that
    re-analysis mends: a model whose lengths or marker positions are off, or a rig off its
    calibration, leaves every image a pixel or more off (docs/BENCH_SUBJECTS.md); so does skin
    that slides (2 px RMS put 31-60 of 60 images of six of the nine bench subjects over the
    default threshold), which no model mends: the threshold is the lab's to set."""
    if not len(per_marker) or over <= MOST_IMAGES_SHARE * len(per_marker):
        return []
    median = float(np.median(per_marker))
    return [f"{over} of {len(per_marker)} images are over the threshold (median {median:.3g} px per "
            f"marker projection, threshold {threshold_px:g}): check the model's segment lengths "
            "and marker positions and the rig's calibration; markers on skin, which slides, "
            "stay a pixel or two off any model: there set error_threshold_px above the typical "
            "error; an overlay of the worst images shows which markers miss"]


def ambiguous_dofs(fits: Iterable[ImageFit], model: KinematicModel) -> dict[str, int]:
    """Per rotational DOF of ``model`` (by name, model-file order), how many of ``fits`` have
    their best alternative farthest from the posture in it (``ImageFit.alternative_dof``: the
    DOF ``alternative_deg`` measures); DOFs in which no image is ambiguous are left out."""
    counts = Counter(f.alternative_dof(model.rotational) for f in fits)
    return {name: counts[d] for d, name in enumerate(model.dof_names) if counts[d]}


def ambiguous_advice(ambiguous: int, fitted: int, by_dof: Mapping[str, int]) -> list[str]:
    """One line of advice when more than :data:`MOST_IMAGES_SHARE` of the ``fitted`` images
    are ambiguous (``ambiguous`` of them), naming the :data:`ADVISED_DOFS` DOFs most often
    ambiguous (``by_dof``, :func:`ambiguous_dofs`), else none. Where most images do not
    determine a DOF, the markers and views do not: the images' residual (sliding skin, a
    model or calibration a little off) leaves it free within the tolerance, and another
    marker on its segment, or a view from another side, pins it (docs/BENCH_SUBJECTS.md).
    ``build_report`` gives it only without :func:`over_threshold_advice`: images most of which
    miss the threshold are ambiguous because of that residual (a rig 8 px off left 40 of 40
    locust images ambiguous), and the line to act on is the one about the model and rig."""
    if not fitted or ambiguous <= MOST_IMAGES_SHARE * fitted:
        return []
    named = sorted(by_dof.items(), key=lambda item: -item[1])[:ADVISED_DOFS]
    return [f"{ambiguous} of {fitted} images are ambiguous (another posture fits about as well: "
            f"alternative_deg), most often in {', '.join(f'{d} ({n})' for d, n in named)}: a marker "
            "on their segments, or a camera that sees them from another side, would determine "
            "them; an overlay marks the ambiguous images"]


def _undetermined(model: KinematicModel) -> list[str] | None:
    """The DOFs the model's markers cannot determine in any posture; None when the model is
    too large to be analysed (``core.identifiability.MAX_ANALYSED_DOFS``)."""
    found = model.identifiability
    return list(found.undetermined) if found.analysed else None


def _stats(values: np.ndarray) -> dict[str, float | None]:
    if values.size == 0:
        return {"mean": None, "median": None, "p95": None, "max": None}
    return {
        "mean": round(float(values.mean()), 4),
        "median": round(float(np.median(values)), 4),
        "p95": round(float(np.percentile(values, 95)), 4),
        "max": round(float(values.max()), 4),
    }

