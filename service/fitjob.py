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


def fit_params(options: JobOptions, marker_diameter_px: float = 0.0) -> FitParams:
    """``FitParams`` of the options, as ``mocap fit`` builds them (raises ValueError).

    marker_diameter_px : the diameter when the options say 'auto' (estimated from the videos).
    """
    diameter = marker_diameter_px if options.marker_diameter_px == "auto" else options.marker_diameter_px
    return FitParams(anneal=AnnealParams().with_iterations(options.iterations),
                     error_threshold_px=options.error_threshold_px,
                     max_attempts=options.max_attempts,
                     fusion_px=fusion_distance(diameter))


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
    # 'auto' is estimated from the first images here, by every process that builds the job:
    # deterministic, so all chunks and re-analyses fit with the same fusion distance.
    diameter = (estimate_marker_diameter(source) or 0.0) if options.marker_diameter_px == "auto" else 0.0
    return FitJob(source, model, fit_params(options, diameter), options.seed,
                  chunk_size(options, default_chunk_size))
