"""The service layer between routes and the database: ownership checked once, commits here.

Every lookup goes through :func:`owned`, so a resource of another lab is
indistinguishable from one that does not exist (404), and no route repeats the
check. Functions that change state commit; routes never do.
"""

from __future__ import annotations

import hashlib
import logging
from typing import Any, TypeVar

from sqlalchemy import Select, func, select, update
from sqlalchemy.orm import Session

from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig
from core.video import VideoError, check_synchronised, probe
from service import histstore, limits
from service.db import rows_changed
from service.errors import ConflictError, InvalidError, NotFoundError
from service.models import (
    TERMINAL,
    Batch,
    Chunk,
    ChunkStatus,
    HistogramVersion,
    Job,
    JobStatus,
    JobVideo,
    Lab,
    Model,
    RigRow,
    Video,
)
from service.redact import redact, stored_names, video_label
from service.schemas import BatchCreate, JobCreate, JobOptions, fit_options
from service.settings import Settings
from service.storage import LocalStorage, Storage

logger = logging.getLogger(__name__)

Owned = TypeVar("Owned", Model, RigRow, Video, Job, Batch)
Upload = TypeVar("Upload", Model, RigRow, Video)


def owned(session: Session, kind: type[Owned], id_: int, lab: Lab) -> Owned:
    """The ``kind`` row ``id_`` if it belongs to ``lab``; otherwise :class:`NotFoundError`."""
    row = session.get(kind, id_)
    if row is None or row.lab_id != lab.id:
        table = kind.__tablename__
        raise NotFoundError(f"{table[:-2] if table.endswith('ches') else table[:-1]} {id_} not found")
    return row


# ---- models and their histogram archive -------------------------------------------------------
def create_model(session: Session, storage: Storage, lab: Lab, xml: bytes, *, name: str | None = None,
                 meta: dict[str, Any] | None = None) -> Model:
    """Validate and store a model; its archive starts with the uniform prior as version 1."""
    kinematic = KinematicModel.from_xml(xml)  # ModelError → 422
    row = Model(lab_id=lab.id, name=name or kinematic.name, xml=xml.decode(),
                sha256=hashlib.sha256(xml).hexdigest(), meta=meta)
    session.add(row)
    session.flush()
    add_histogram_version(session, storage, row, Histograms.uniform(kinematic), job_id=None)
    session.commit()
    return row


def store_model(session: Session, storage: Storage, lab: Lab, xml: bytes, *, name: str | None,
                meta: dict[str, Any] | None, reuse: bool) -> tuple[Model, Model | None]:
    """(the model, an identical one the lab uploaded before or None). With ``reuse`` and such a
    model, that model itself and nothing stored: jobs on it go on with its histogram archive."""
    existing = identical_model(session, lab, hashlib.sha256(xml).hexdigest())
    if reuse and existing is not None:
        return existing, existing
    return create_model(session, storage, lab, xml, name=name, meta=meta), existing


def identical_model(session: Session, lab: Lab, sha256: str) -> Model | None:
    """The lab's model whose XML has this ``sha256`` and whose histogram archive has the most
    versions (the most jobs folded in; the oldest on a tie); None if none. Only ``lab``'s models
    are searched: another lab's identical model is never revealed."""
    versions = func.count(HistogramVersion.id)
    query = (select(Model).join(HistogramVersion, HistogramVersion.model_id == Model.id)
             .where(Model.lab_id == lab.id, Model.sha256 == sha256)
             .group_by(Model.id).order_by(versions.desc(), Model.id).limit(1))
    return session.scalars(query).first()


def add_histogram_version(
    session: Session, storage: Storage, model: Model, histograms: Histograms, *, job_id: int | None
) -> HistogramVersion:
    """Store ``histograms`` as the model's next archive version (caller holds the model's lock)."""
    latest = session.scalar(select(func.max(HistogramVersion.version))
                            .where(HistogramVersion.model_id == model.id)) or 0
    key = f"models/{model.id}/histograms-v{latest + 1}.npz"
    histstore.save(storage, key, histograms)
    version = HistogramVersion(model_id=model.id, version=latest + 1, storage_key=key, job_id=job_id)
    session.add(version)
    session.flush()
    return version


def histogram_version(session: Session, model: Model, version: int | None) -> HistogramVersion:
    """Version ``version`` of the model's archive, or the latest."""
    query = select(HistogramVersion).where(HistogramVersion.model_id == model.id)
    query = (query.where(HistogramVersion.version == version) if version is not None
             else query.order_by(HistogramVersion.version.desc()).limit(1))
    row = session.scalars(query).first()
    if row is None:
        raise NotFoundError(f"model {model.id} has no histogram version {version}")
    return row


def histogram_versions(session: Session, model: Model) -> int:
    return session.scalar(select(func.count()).where(HistogramVersion.model_id == model.id)) or 0


# ---- rigs and videos --------------------------------------------------------------------------
def create_rig(session: Session, lab: Lab, spec: Any, *, name: str | None = None,
               meta: dict[str, Any] | None = None) -> RigRow:
    Rig.from_dict(spec)  # RigError → 422
    row = RigRow(lab_id=lab.id, spec=spec, name=name, meta=meta)
    session.add(row)
    session.commit()
    return row


def register_video(
    session: Session, storage: LocalStorage, lab: Lab, settings: Settings, *, key: str, filename: str,
    size: int, sha256: str, name: str | None = None, meta: dict[str, Any] | None = None,
) -> Video:
    """Probe a fully stored upload and register it within the lab's hourly upload limits.

    The file is deleted on any failure, so no stored video is without its row: unusable
    (VideoError → 422, naming ``filename``, never the server's path), over a limit
    (RateLimitedError → 429), or a failed INSERT.
    """
    path = storage.path(key)
    try:
        try:
            info = probe(path)
        except VideoError as exc:
            names = stored_names(key, path, repr(filename))
            raise VideoError(redact(str(exc), names, storage.root)) from None
        limits.lock_lab(session, lab)
        limits.check_upload(session, lab, settings, size)
        row = Video(lab_id=lab.id, storage_key=key, filename=filename, frames=info.frames,
                    announced_frames=info.announced_frames, fps=info.fps, width=info.width,
                    height=info.height, size_bytes=size, sha256=sha256, name=name, meta=meta)
        session.add(row)
        session.commit()
    except BaseException:
        session.rollback()
        storage.delete(key)
        raise
    return row


def missing_frames(video: Video) -> str | None:
    """Say so when the container announces frames that do not decode (a truncated file)."""
    if not video.announced_frames or video.announced_frames <= video.frames:
        return None
    return (f"{video_label(video)}: the file announces {video.announced_frames} frames but only "
            f"{video.frames} decode ({video.announced_frames - video.frames} missing: truncated?); "
            f"jobs fit the {video.frames} that decode")


def remove_orphans(session: Session, storage: LocalStorage, older_than_s: float) -> int:
    """Delete stored videos and histogram archive files that no row names, if older than
    ``older_than_s`` (younger ones may be being registered). They are left when a process dies
    between storing a file and committing its row, or between deleting a row and its file
    (:func:`delete_upload`)."""
    folders = [("videos", Video.storage_key),
               *((folder, HistogramVersion.storage_key) for folder in storage.folders("models"))]
    return sum(_remove_unnamed(session, storage, folder, column, older_than_s) for folder, column in folders)


def _remove_unnamed(session: Session, storage: LocalStorage, folder: str, column: Any,
                    older_than_s: float) -> int:
    """Delete the files of ``folder`` whose key no row has in ``column``."""
    stored = dict(storage.files(folder, older_than_s))
    keys, known = list(stored), set[str]()
    for start in range(0, len(keys), 500):  # bound values per statement (SQLite: 32,766)
        batch = keys[start:start + 500]
        known.update(session.scalars(select(column).where(column.in_(batch))))
    orphans = [key for key in keys if key not in known]
    for key in orphans:
        storage.delete(key)
    if orphans:
        logger.warning("removed %d stored file(s) in %s without a row (%d bytes)", len(orphans), folder,
                       sum(stored[k] for k in orphans))
    return len(orphans)


# ---- deleting uploads ---------------------------------------------------------------------------
# Jobs listed by id in a 409; more are counted.
USERS_SHOWN = 20


def delete_upload(session: Session, storage: Storage, lab: Lab, kind: type[Upload],
                  id_: int) -> None:
    """Delete the lab's model, rig or video, unless a job uses it (409 naming the jobs).

    "Uses" is any job that names it, finished ones too: a finished job's archive carries its
    model and rig, its report names its videos, and the rows keep those ids meaningful. The
    row (and a model's archive rows) go in one transaction, with the lab locked as submissions
    lock it, so no job can start using it meanwhile; the stored files go after the commit. A
    crash in between leaves files no row names, which :func:`remove_orphans` deletes: never a
    row without its file.
    """
    row = owned(session, kind, id_, lab)
    limits.lock_lab(session, lab)
    label = f"{kind.__tablename__[:-1]} {id_}"
    if users := jobs_using(session, row):
        shown = ", ".join(str(j) for j in users[:USERS_SHOWN])
        more = f" and {len(users) - USERS_SHOWN} more" if len(users) > USERS_SHOWN else ""
        raise ConflictError(f"{label} is used by job(s) {shown}{more}; an upload a job names (finished "
                            "or not) cannot be deleted: its results and archive refer to it")
    keys = [row.storage_key] if isinstance(row, Video) else []
    if isinstance(row, Model):
        versions = list(session.scalars(select(HistogramVersion).where(HistogramVersion.model_id == row.id)))
        keys = [v.storage_key for v in versions]
        for version in versions:
            session.delete(version)
        session.flush()  # the versions' rows go before the model's (their foreign key)
    session.delete(row)
    session.commit()
    for key in keys:
        storage.delete(key)
    logger.info("lab %s deleted %s (%d stored file(s))", lab.id, label, len(keys))


def jobs_using(session: Session, row: Model | RigRow | Video) -> list[int]:
    """Ids of the jobs (any status) that name ``row``, ascending."""
    if isinstance(row, Video):
        query = select(JobVideo.job_id).where(JobVideo.video_id == row.id)
    else:
        query = select(Job.id).where((Job.model_id if isinstance(row, Model) else Job.rig_id) == row.id)
    return sorted(set(session.scalars(query)))


# ---- jobs and batches ---------------------------------------------------------------------------
def submit_job(session: Session, lab: Lab, settings: Settings, body: JobCreate) -> Job:
    """Create a queued job (committed) within the lab's limits; the caller enqueues its planning task."""
    limits.lock_lab(session, lab)
    limits.check_active_jobs(session, lab, settings, 1)
    job = _new_job(session, lab, settings, body.model_id, body.rig_id, body.video_ids, body.options,
                   name=body.name, meta=body.metadata)
    session.commit()
    return job


def submit_batch(session: Session, lab: Lab, settings: Settings,
                 body: BatchCreate) -> tuple[Batch, list[Job]]:
    """One job per trial, all or none (committed together), within the lab's limits."""
    limits.lock_lab(session, lab)
    limits.check_active_jobs(session, lab, settings, len(body.trials))
    batch = Batch(lab_id=lab.id, name=body.name, meta=body.metadata)
    session.add(batch)
    session.flush()
    jobs = [
        _new_job(session, lab, settings, body.model_id, body.rig_id, trial.video_ids, body.options,
                 batch=batch, trial=i, name=trial.name, meta=trial.metadata)
        for i, trial in enumerate(body.trials)
    ]
    session.commit()
    return batch, jobs


def _new_job(
    session: Session, lab: Lab, settings: Settings, model_id: int, rig_id: int, video_ids: list[int],
    options: JobOptions, *, batch: Batch | None = None, trial: int | None = None, name: str | None = None,
    meta: dict[str, Any] | None = None,
) -> Job:
    model = owned(session, Model, model_id, lab)
    rig = Rig.from_dict(owned(session, RigRow, rig_id, lab).spec)
    videos = [owned(session, Video, v, lab) for v in video_ids]
    if len(videos) != rig.n_videos:
        raise InvalidError(f"rig {rig_id} expects {rig.n_videos} video(s), the job names {len(videos)}")
    # A roi or a camera's principal point outside its frame → 422 now
    rig.check_videos([(v.width, v.height) for v in videos], [video_label(v) for v in videos])
    # Videos that cannot be read as one set (as `mocap fit` reads them) → 422 now, not in a worker.
    check_synchronised([video_label(v) for v in videos], [v.frames for v in videos], [v.fps for v in videos])
    limits.check_frames(videos, settings)
    fit = fit_options(options)  # OptionError (ValueError) naming the option → 422
    if fit.root_marker is not None:
        fit.root_tracking(KinematicModel.from_xml(model.xml), rig)  # its marker and views → 422 now
    # The cost with the diameter not yet estimated: the fusion distance does not change it.
    limits.check_cost(model, rig, fit.fit_params(0.0), videos, 2 if fit.deinterlace else 1, settings)
    start = histogram_version(session, model, options.histogram_version)
    job = Job(lab_id=lab.id, model_id=model.id, rig_id=rig_id, options=options.model_dump(),
              histogram_version_id=start.id, batch_id=None if batch is None else batch.id, trial=trial,
              name=name, meta=meta, status=JobStatus.QUEUED)
    session.add(job)
    session.flush()
    session.add_all(JobVideo(job_id=job.id, position=i, video_id=v.id) for i, v in enumerate(videos))
    return job


def cancel_job(session: Session, lab: Lab, job_id: int) -> Job:
    """Mark a job canceled unless it has ended, and its chunks no worker has started with it;
    running chunks see it between images."""
    job = owned(session, Job, job_id, lab)
    if rows_changed(session, update(Job).where(Job.id == job.id, Job.status.not_in(list(TERMINAL)))
                    .values(status=JobStatus.CANCELED, error="canceled by the user")):
        session.execute(update(Chunk).where(Chunk.job_id == job.id, Chunk.status == ChunkStatus.QUEUED)
                        .values(status=ChunkStatus.CANCELED))
    session.commit()
    session.refresh(job)
    return job


def fail_unqueued(session: Session, jobs: list[Job], message: str) -> None:
    """Fail jobs whose planning task could not be queued (still ``queued``), saying why."""
    session.execute(update(Job).where(Job.id.in_([j.id for j in jobs]), Job.status == JobStatus.QUEUED)
                    .values(status=JobStatus.FAILED, error=message))
    session.commit()


def list_jobs(
    session: Session, lab: Lab, *, status: JobStatus | None, cursor: int | None, limit: int,
    batch_id: int | None = None,
) -> tuple[list[Job], int | None]:
    """The lab's jobs, newest first, ``limit`` per page after ``cursor`` (a job id)."""
    query = select(Job).where(Job.lab_id == lab.id)
    if status is not None:
        query = query.where(Job.status == status)
    if batch_id is not None:
        query = query.where(Job.batch_id == batch_id)
    return page(session, query, Job, cursor=cursor, limit=limit)


def list_owned(session: Session, kind: type[Owned], lab: Lab, *, cursor: int | None,
               limit: int) -> tuple[list[Owned], int | None]:
    """The lab's ``kind`` rows (models, rigs, videos), newest first, ``limit`` per page after ``cursor``."""
    return page(session, select(kind).where(kind.lab_id == lab.id), kind, cursor=cursor, limit=limit)


def page(session: Session, query: Select[Owned], kind: type[Owned], *, cursor: int | None,
         limit: int) -> tuple[list[Owned], int | None]:
    """One page of ``query``'s rows by descending id: the rows with id < ``cursor`` (all for None),
    at most ``limit``, and the cursor of the next page (None: this is the last)."""
    if cursor is not None:
        query = query.where(kind.id < cursor)
    rows = list(session.scalars(query.order_by(kind.id.desc()).limit(limit + 1)))
    more = len(rows) > limit
    rows = rows[:limit]
    return rows, (rows[-1].id if more and rows else None)


def batch_jobs(session: Session, batch: Batch) -> list[Job]:
    return list(session.scalars(select(Job).where(Job.batch_id == batch.id).order_by(Job.trial)))


def result_key(session: Session, lab: Lab, job_id: int, name: str) -> str:
    """Storage key of a finished job's result file; 409 until the job has succeeded."""
    job = owned(session, Job, job_id, lab)
    if job.status != JobStatus.SUCCEEDED:
        raise ConflictError(f"job {job.id} is {job.status}; results exist once it has succeeded")
    return f"jobs/{job.id}/{name}"
