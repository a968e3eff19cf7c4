"""From database rows to ``core`` objects: a job's options become a fit (``core.options.build_fit``).

The API validates the options with the same ``core.options.FitOptions`` at submission, so a
job the API accepted builds in a worker.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from core.model import KinematicModel
from core.options import Fit, build_fit
from core.rig import Rig
from service import histstore
from service.models import HistogramVersion, Job, JobVideo, Model, RigRow, Video
from service.schemas import JobOptions, fit_options
from service.storage import Storage


def build_fit_job(session: Session, job: Job, storage: Storage, default_chunk_size: int) -> Fit:
    """The fit of a job row (``core.pipeline.FitJob`` and starting histograms), its videos read
    from storage.

    The starting histograms are the job's version of its model's archive; a version that is the
    uniform prior (no job folded in) is made with the options' ``prior_weight``.
    """
    options = fit_options(JobOptions.model_validate(job.options))
    if options.chunk_size is None:
        options = replace(options, chunk_size=default_chunk_size)
    model = KinematicModel.from_xml(session.get_one(Model, job.model_id).xml)
    rig = Rig.from_dict(session.get_one(RigRow, job.rig_id).spec)
    keys = session.scalars(
        select(Video.storage_key).join(JobVideo, JobVideo.video_id == Video.id)
        .where(JobVideo.job_id == job.id).order_by(JobVideo.position)
    ).all()
    paths: tuple[Path, ...] = tuple(storage.path(k) for k in keys)
    version = session.get_one(HistogramVersion, job.histogram_version_id)
    start = None if version.job_id is None else histstore.load(storage, version.storage_key, model)
    return build_fit(options, model, rig, paths, start)
