"""From database rows to ``core`` objects: the job's options become a ``core.pipeline.FitJob``.

The API validates options with the same functions, so a job the API accepted
builds in a worker.
"""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from core.anneal import AnnealParams
from core.detect import DetectorParams
from core.error import fusion_distance
from core.fit import FitParams
from core.model import KinematicModel
from core.pipeline import FitJob, VideoSource, estimate_marker_diameter
from core.rig import Rig
from service.models import Job, JobVideo, Model, RigRow, Video
from service.schemas import JobOptions
from service.storage import Storage


def fit_params(options: JobOptions, marker_diameter_px: float) -> FitParams:
    """``FitParams`` of the options, as ``mocap fit`` builds them (raises ValueError).

    marker_diameter_px : the diameter :func:`marker_diameter` resolved for these options.
    """
    return FitParams(anneal=AnnealParams().with_iterations(options.iterations),
                     error_threshold_px=options.error_threshold_px,
                     max_attempts=options.max_attempts,
                     fusion_px=fusion_distance(marker_diameter_px))


def marker_diameter(options: JobOptions, source: VideoSource | None) -> float:
    """The options' marker diameter; 'auto' is estimated from the first images of ``source``
    (0 without a source, to validate the other options at submission).

    Every process that builds the job estimates it the same way (deterministic), so all
    chunks and re-analyses fit with the same fusion distance.
    """
    if options.marker_diameter_px != "auto":
        return options.marker_diameter_px
    return (estimate_marker_diameter(source) or 0.0) if source is not None else 0.0


def detector_params(options: JobOptions) -> DetectorParams:
    return DetectorParams(**options.detector.model_dump())


def chunk_size(options: JobOptions, default: int) -> int:
    return options.chunk_size or default


def build_fit_job(session: Session, job: Job, storage: Storage, default_chunk_size: int) -> FitJob:
    """The ``core.pipeline.FitJob`` of a job row, its videos read from storage."""
    options = JobOptions.model_validate(job.options)
    model = KinematicModel.from_xml(session.get_one(Model, job.model_id).xml)
    rig = Rig.from_dict(session.get_one(RigRow, job.rig_id).spec)
    keys = session.scalars(
        select(Video.storage_key).join(JobVideo, JobVideo.video_id == Video.id)
        .where(JobVideo.job_id == job.id).order_by(JobVideo.position)
    ).all()
    paths: tuple[Path, ...] = tuple(storage.path(k) for k in keys)
    source = VideoSource(paths, rig, detector_params(options), options.deinterlace, options.field_order)
    return FitJob(source, model, fit_params(options, marker_diameter(options, source)), options.seed,
                  chunk_size(options, default_chunk_size))
