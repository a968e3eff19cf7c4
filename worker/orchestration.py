"""The whole life of a job, driven by database state: plan → chunks → merge → re-analysis → finish.

Every step of the fit is a ``core`` function, the one ``mocap fit`` calls (``core.sequence``,
``core.pipeline``); this module adds the database, the queue, claiming, heartbeats and
idempotence:

1. :func:`plan_job` (``core.pipeline.plan``): chunk rows, one ``fit_chunk`` task each.
2. :func:`run_chunk` (``core.sequence.fit_chunk``): the chunk's image rows (attempt 1)
   and its observed histogram counts, stored exactly (``.npz``). Marking the chunk
   done and counting it on the job is one guarded UPDATE; the chunk whose UPDATE
   brings ``chunks_done`` to ``chunks_total`` is the last, and only it goes on:
   A thread writes the chunk's heartbeat meanwhile; ``worker.reaper`` sends again a
   chunk whose heartbeat stops (its worker died as a whole).
3. :func:`_after_chunks` (``core.sequence.plan_reanalysis``): merged histograms, one
   ``reanalyse_image`` task per image to re-fit, ``reanalyses_pending`` on the job.
4. :func:`run_attempt` (``core.fit.reanalyse_image``): one attempt, keeping the best;
   the next attempt is queued while the image still needs one; the task that brings
   ``reanalyses_pending`` to 0 finishes the job.
5. :func:`_finish` (``core.sequence.finish_sequence``, ``core.pipeline.outputs``):
   angles.csv, histograms.xml, report.json, the exports for other tools (``core.export``:
   .mot, .trc, .c3d, and detections.csv joined from the chunks'), and the job's
   observations folded into the model's histogram archive as a new version.

:func:`resume` runs step 3 or 5 again for a job whose worker died just before it (the
reaper sends it once the job has stopped moving).

Idempotence: image and attempt rows are inserted keyed by (job, sample[, attempt])
and a second insert is ignored (fits are deterministic per seed, sample and attempt);
every transition is an UPDATE guarded by the expected current state, acting only if
it changed a row. Tasks are queued only after the transaction that needs them commits.
"""

from __future__ import annotations

import io
import logging
import os
import shutil
import tempfile
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from core.error import Detections
from core.export import DETECTIONS_FILE, DETECTIONS_HEADER, EXPORT_FILES, export, write_detections_csv
from core.fit import ImageFit, Status, needs_reanalysis, reanalyse_image
from core.histogram import Histograms
from core.model import KinematicModel
from core.pipeline import FitJob, FitOutcome, Outputs, outputs, plan
from core.results import read_angles_csv
from core.sequence import SequenceResult, finish_sequence, fit_chunk, images_to_reanalyse, plan_reanalysis
from service import artifacts, broker, histstore
from service.broker import FIT_CHUNK, REANALYSE_IMAGE
from service.crud import add_histogram_version, histogram_version, missing_frames
from service.db import rows_changed, session_scope
from service.fitjob import build_fit_job
from service.models import (
    TERMINAL,
    Attempt,
    Batch,
    Chunk,
    ChunkStatus,
    ImageResult,
    Job,
    JobStatus,
    JobVideo,
    Model,
    RigRow,
    Video,
    utcnow,
)
from service.redact import redact, video_names
from service.schemas import JobOptions
from service.settings import get_settings
from service.storage import Storage, get_storage

logger = logging.getLogger(__name__)

_INSERT_BATCH = 500  # rows per INSERT: SQLite allows 32,766 bound values per statement


@dataclass
class _Loaded:
    """A job row with its core objects: what every step needs."""

    job: Job
    fit: FitJob
    prior: Histograms


_CACHE_SIZE = 8
_core_cache: OrderedDict[int, tuple[FitJob, Histograms]] = OrderedDict()


def _load(session: Session, job_id: int) -> _Loaded:
    """The job row and its core objects. The FitJob and the starting histograms never change
    after submission, and building them probes the videos (decoding frames), so each worker
    process builds them once per job, not once per chunk."""
    job = session.get_one(Job, job_id)
    if job_id not in _core_cache:
        storage = get_storage()
        built = build_fit_job(session, job, storage, get_settings().default_chunk_size)
        _core_cache[job_id] = (built.job, built.start)
        while len(_core_cache) > _CACHE_SIZE:
            _core_cache.popitem(last=False)
    _core_cache.move_to_end(job_id)
    fit, prior = _core_cache[job_id]
    return _Loaded(job, fit, prior.copy())


# ---- 1. plan ----------------------------------------------------------------------------------
def plan_job(job_id: int) -> None:
    """Count images, create chunk rows and queue them (only for a job still queued).

    The job row is locked first: a second delivery running at the same time (a message
    the reaper thought lost) waits here, then finds the job running and does nothing,
    rather than inserting the same chunks again.
    """
    with session_scope() as session:
        job = session.get_one(Job, job_id, with_for_update=True)
        if job.status != JobStatus.QUEUED:
            logger.info("job %s is %s: nothing to plan", job_id, job.status)
            return
        steps = plan(_load(session, job_id).fit)
        if steps.offsets is not None:  # root tracking runs once, over the whole sequence
            get_storage().put(_offsets_key(job_id), [_npy(steps.offsets)])
        # Guarded: with SQLite (no row locks) a cancel may have come in while the videos were probed.
        if not rows_changed(session, update(Job).where(Job.id == job_id, Job.status == JobStatus.QUEUED)
                        .values(status=JobStatus.RUNNING, started_at=utcnow(), images_total=steps.images,
                                chunks_total=len(steps.chunks))):
            return
        now = utcnow()
        chunks = [Chunk(job_id=job_id, index=i, first=a, last=b, queued_at=now)
                  for i, (a, b) in enumerate(steps.chunks)]
        session.add_all(chunks)
        session.flush()
        ids = [c.id for c in chunks]
    logger.info("job %s: %d images in %d chunks", job_id, steps.images, len(ids))
    for chunk_id in ids:
        broker.enqueue(FIT_CHUNK, chunk_id)


def _offsets_key(job_id: int) -> str:
    return f"jobs/{job_id}/root_offsets.npy"


def _npy(array: NDArray[np.float64]) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


def _root_offsets(job_id: int, fit: FitJob, first: int, last: int) -> NDArray[np.float64] | None:
    """The planned root-tracking offsets of images ``[first, last)``, (last - first, V, 2), or
    None without root tracking."""
    if fit.root is None:
        return None
    with get_storage().open(_offsets_key(job_id)) as f:
        offsets: NDArray[np.float64] = np.load(f, allow_pickle=False)
    return offsets[first:last]


# ---- 2. chunks --------------------------------------------------------------------------------
def run_chunk(chunk_id: int, *, worker: str) -> None:
    """Fit one chunk, store its rows and counts, and go on to step 3 if it was the last."""
    with session_scope() as session:
        chunk = session.get_one(Chunk, chunk_id)
        if not _claim(session, chunk, worker):
            return
        first, last, job_id, index = chunk.first, chunk.last, chunk.job_id, chunk.index
    with _heartbeat(chunk_id):  # from the claim on: loading probes the videos, seconds on a cold process
        with session_scope() as session:
            loaded = _load(session, job_id)
        _crash_if_told(job_id, index)
        seen: list[Detections] = []
        fit = loaded.fit
        result = fit_chunk(_kept(fit.source[first:last], seen), model=fit.model, rig=fit.source.framed_rig,
                           histograms=loaded.prior, params=fit.params, seed=fit.seed, first_sample=first,
                           offsets=_root_offsets(job_id, fit, first, last),
                           should_stop=_canceled_check(job_id))
    if len(result.fits) < last - first:
        _set_chunk(chunk_id, ChunkStatus.CANCELED)
        logger.info("chunk %s of job %s stopped: job canceled", index, job_id)
        return
    _put_chunk_detections(job_id, index, first, loaded.fit, seen)
    key = f"jobs/{job_id}/chunks/{index}.npz"
    histstore.save(get_storage(), key, result.observed)
    if _complete_chunk(chunk_id, job_id, key, result.fits, worker):
        _crash_if_told(job_id, index, "done")
        _after_chunks(job_id)


def _kept(images: Iterable[Detections], seen: list[Detections]) -> Iterator[Detections]:
    """``images``, each appended to ``seen`` before it is fitted (the chunk's ``detections.csv``)."""
    for det in images:
        seen.append(det)
        yield det


def _claim(session: Session, chunk: Chunk, worker: str) -> bool:
    """Start (or restart, after a lost delivery) a chunk that is not done and whose job runs.

    A chunk already started ``max_chunk_attempts`` times crashed or stalled its worker each
    time (Celery hands a message back when its worker dies, the reaper when its heartbeat
    stops): it fails, and its job with it, instead of taking down workers for ever.
    """
    job = session.get_one(Job, chunk.job_id)
    if job.status != JobStatus.RUNNING or chunk.status in (ChunkStatus.DONE, ChunkStatus.FAILED):
        logger.info("chunk %s skipped: chunk %s, job %s", chunk.id, chunk.status, job.status)
        return False
    limit = get_settings().max_chunk_attempts
    if chunk.attempts >= limit:
        message = (f"chunk {chunk.index} (images {chunk.first}-{chunk.last - 1}) was started "
                   f"{chunk.attempts} times and never finished: its worker died or stalled each time "
                   f"(MOCAP_MAX_CHUNK_ATTEMPTS={limit})")
        logger.error("job %s: %s", job.id, message)
        chunk.status, chunk.error = ChunkStatus.FAILED, message
        session.execute(update(Job).where(Job.id == job.id, Job.status.not_in(list(TERMINAL)))
                        .values(status=JobStatus.FAILED, error=message, finished_at=utcnow()))
        return False
    chunk.status, chunk.worker, chunk.heartbeat_at = ChunkStatus.RUNNING, worker, utcnow()
    chunk.attempts += 1
    return True


def _crash_if_told(job_id: int, index: int, when: str = "") -> None:
    """Test-only fault injection: ``MOCAP_CRASH_CHUNK=JOB:INDEX`` dies as the chunk starts, like a
    poison input would; ``JOB:INDEX:done`` right after the chunk is counted done, before the merge.
    No cleanup, so the tests exercise the real crash path (Celery's worker-lost hand-back)."""
    if get_settings().crash_chunk == f"{job_id}:{index}" + (f":{when}" if when else ""):
        logger.error("MOCAP_CRASH_CHUNK: worker process exits on chunk %s of job %s", index, job_id)
        logging.shutdown()
        os._exit(1)


def _canceled_check(job_id: int) -> Callable[[], bool]:
    """``should_stop`` for ``fit_chunk``: reads the job's status at most every cancel_check_s."""
    interval, state = get_settings().cancel_check_s, {"at": time.monotonic(), "stop": False}

    def should_stop() -> bool:
        if not state["stop"] and time.monotonic() - state["at"] >= interval:
            state["at"] = time.monotonic()
            with session_scope() as session:
                state["stop"] = session.get_one(Job, job_id).status in TERMINAL
        return bool(state["stop"])

    return should_stop


@contextmanager
def _heartbeat(chunk_id: int) -> Iterator[None]:
    """Write the chunk's heartbeat every heartbeat_s from a thread while the block runs.

    A thread, not a per-image callback: the first image of a process can take a minute
    (numba compiles the kernels on a cold cache) and the reaper must not take that for a dead
    worker. The heartbeat says the process lives; a hung fit is Celery's time limits' job.
    """
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(get_settings().heartbeat_s):
            try:
                with session_scope() as session:
                    session.execute(update(Chunk).where(Chunk.id == chunk_id).values(heartbeat_at=utcnow()))
            except Exception:  # a database blip: the next beat may get through
                logger.exception("heartbeat of chunk %s not written", chunk_id)

    thread = threading.Thread(target=beat, name=f"heartbeat-{chunk_id}", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def _put_chunk_detections(job_id: int, index: int, first: int, fit: FitJob, seen: list[Detections]) -> None:
    """The chunk's rows of detections.csv (no header); :func:`_finish` joins the chunks'."""
    text = io.StringIO()
    write_detections_csv(text, seen, fit.source.rig, fit.clock, first_sample=first, header=False)
    get_storage().put(f"jobs/{job_id}/chunks/{index}.detections.csv", [text.getvalue().encode()])


def _complete_chunk(chunk_id: int, job_id: int, key: str, fits: list[ImageFit], worker: str) -> bool:
    """Store the chunk's fits and count it done; True for the job's last chunk."""
    over = sum(f.status is Status.OVER_THRESHOLD for f in fits)
    with session_scope() as session:
        _insert_ignore(session, ImageResult, [_image_row(job_id, f) for f in fits])
        _insert_ignore(session, Attempt, [_attempt_row(job_id, f, worker) for f in fits])
        done = rows_changed(session,
            update(Chunk).where(Chunk.id == chunk_id, Chunk.status != ChunkStatus.DONE)
            .values(status=ChunkStatus.DONE, observed_key=key, heartbeat_at=utcnow())
        )
        if not done:
            return False
        counts = session.execute(
            update(Job).where(Job.id == job_id)
            .values(chunks_done=Job.chunks_done + 1, images_done=Job.images_done + len(fits),
                    images_over_threshold=Job.images_over_threshold + over)
            .returning(Job.chunks_done, Job.chunks_total, Job.status)
        ).one()
    return bool(counts.chunks_done == counts.chunks_total and counts.status == JobStatus.RUNNING)


# ---- 3. merge and queue re-analysis -------------------------------------------------------------
def _after_chunks(job_id: int) -> None:
    storage = get_storage()
    with session_scope() as session:
        loaded = _load(session, job_id)
        keys = session.scalars(select(Chunk.observed_key).where(Chunk.job_id == job_id)
                               .order_by(Chunk.index)).all()
        observed = [histstore.load(storage, k, loaded.fit.model) for k in keys if k]
        todo = plan_reanalysis(loaded.prior, observed, _fits(session, job_id), loaded.fit.model,
                               loaded.fit.params)
        histstore.save(storage, f"jobs/{job_id}/merged.npz", todo.histograms)
        moved = rows_changed(session,
            update(Job).where(Job.id == job_id, Job.status == JobStatus.RUNNING, Job.fitted_at.is_(None))
            .values(typical_objective=todo.typical, reanalyses_pending=len(todo.images),
                    fitted_at=utcnow(), progress_at=utcnow(),
                    status=JobStatus.REANALYSING if todo.images else JobStatus.RUNNING)
        )
    if not moved:
        return
    logger.info("job %s: all chunks done, %d images to re-analyse", job_id, len(todo.images))
    for sample, attempt in todo.images:
        broker.enqueue(REANALYSE_IMAGE, job_id, sample, attempt)
    if not todo.images:
        _finish(job_id)


# ---- 4. re-analysis -----------------------------------------------------------------------------
def run_attempt(job_id: int, sample: int, attempt: int, *, worker: str) -> None:
    """Attempt ``attempt`` on image ``sample`` of a re-analysing job, stored and counted:
    skipped unless it is the image's next attempt."""
    with session_scope() as session:
        job = session.get_one(Job, job_id)
        row = session.scalars(select(ImageResult).where(ImageResult.job_id == job_id,
                                                        ImageResult.sample == sample)).one()
        if job.status != JobStatus.REANALYSING or row.attempts != attempt - 1:
            return
        loaded = _load(session, job_id)
        typical = _typical(job)
        previous = ImageFit.from_record(row.record)
    merged = histstore.load(get_storage(), f"jobs/{job_id}/merged.npz", loaded.fit.model)
    fit_job = loaded.fit
    offsets = _root_offsets(job_id, fit_job, sample, sample + 1)
    fit = reanalyse_image(fit_job.source[sample], previous, model=fit_job.model,
                          rig=fit_job.source.framed_rig, histograms=merged, params=fit_job.params,
                          seed=fit_job.seed, typical=typical,
                          offsets=None if offsets is None else offsets[0])
    again = needs_reanalysis(fit, fit_job.model, fit_job.params, typical)
    over = int(fit.status is Status.OVER_THRESHOLD) - int(previous.status is Status.OVER_THRESHOLD)
    with session_scope() as session:
        stored = rows_changed(session,
            update(ImageResult).where(ImageResult.job_id == job_id, ImageResult.sample == sample,
                                      ImageResult.attempts == attempt - 1)
            .values(**_image_row(job_id, fit))
        )
        if not stored:
            return
        _insert_ignore(session, Attempt, [_attempt_row(job_id, fit, worker)])
        values: dict[str, Any] = {"images_over_threshold": Job.images_over_threshold + over,
                                  "progress_at": utcnow()}
        if not again:
            values["reanalyses_pending"] = Job.reanalyses_pending - 1
        left = session.execute(update(Job).where(Job.id == job_id).values(**values)
                               .returning(Job.reanalyses_pending)).scalar_one()
    if again:
        broker.enqueue(REANALYSE_IMAGE, job_id, sample, attempt + 1)
    elif left == 0:
        _finish(job_id)


def pending_reanalyses(session: Session, job_id: int) -> list[tuple[int, int]]:
    """(sample, next attempt) of every image of a re-analysing job that still needs one: read
    from the stored fits with the rule that queued them, so lost messages can be sent again."""
    job = session.get_one(Job, job_id)
    fit_job = _load(session, job_id).fit
    return images_to_reanalyse(_fits(session, job_id), fit_job.model, fit_job.params, _typical(job))


def _typical(job: Job) -> float:
    """The typical objective step 3 stored on the job (NaN when no image had detections)."""
    return job.typical_objective if job.typical_objective is not None else float("nan")


def resume(job_id: int) -> None:
    """Step 3 or 5 for a job whose worker died after the step before committed (sent by the
    reaper): every chunk done but never merged, or nothing pending but never finished."""
    with session_scope() as session:
        job = session.get_one(Job, job_id)
        status, merged, pending = job.status, job.fitted_at is not None, job.reanalyses_pending
        all_done = job.chunks_total > 0 and job.chunks_done == job.chunks_total
    if status == JobStatus.RUNNING and all_done and not merged:
        _after_chunks(job_id)
    elif status in (JobStatus.RUNNING, JobStatus.REANALYSING) and all_done and merged and pending == 0:
        _finish(job_id)
    else:
        logger.info("job %s is %s: nothing to resume", job_id, status)


# ---- 5. finish ---------------------------------------------------------------------------------
def _finish(job_id: int) -> None:
    """Write the results (and the artifacts the options ask for: drawn with no transaction
    open, they decode the videos again), fold the job into the model's archive as a new
    version where an image was within the threshold (none: the archive is unchanged, and a
    version would repeat the last), then mark it succeeded."""
    storage = get_storage()
    with session_scope() as session:
        loaded = _load(session, job_id)
        fits = _fits(session, job_id)
        result = finish_sequence(loaded.prior, fits, model=loaded.fit.model, params=loaded.fit.params)
        results = _outputs(session, loaded, result, fits)
        _put_exports(storage, job_id, results.angles_csv, loaded.fit.model)
        _join_detections(session, storage, job_id)
        model_id, options = loaded.job.model_id, JobOptions.model_validate(loaded.job.options)
    if options.overlay or options.plots:
        results.report["artifacts"] = artifacts.render(storage, job_id, loaded.fit, loaded.prior, result,
                                                       overlay=options.overlay, plots=options.plots)
    for name, text in results.files().items():  # report.json last
        storage.put(f"jobs/{job_id}/{name}", [text.encode()])
    with session_scope() as session:
        model = session.scalars(select(Model).where(Model.id == model_id)
                                .with_for_update()).one()  # one fold at a time per model
        ended = rows_changed(session,
            update(Job).where(Job.id == job_id, Job.status.in_([JobStatus.RUNNING, JobStatus.REANALYSING]))
            .values(status=JobStatus.SUCCEEDED, finished_at=utcnow(), reanalyses_pending=0,
                    images_over_threshold=sum(f.status is Status.OVER_THRESHOLD for f in result.fits))
        )
        if not ended:
            session.rollback()
            return
        if not result.observed.counts.any():  # no image within the threshold: nothing to fold in
            logger.info("job %s succeeded; no image within the threshold, model %s archive unchanged",
                        job_id, model.id)
            return
        latest = histogram_version(session, model, None)
        archive = histstore.load(storage, latest.storage_key, loaded.fit.model)
        version = add_histogram_version(session, storage, model, archive.merge(result.observed),
                                        job_id=job_id)
    logger.info("job %s succeeded; model %s archive version %s", job_id, model.id, version.version)


def _put_exports(storage: Storage, job_id: int, angles_csv: str, model: KinematicModel) -> None:
    """angles.mot, markers.trc and markers.c3d of the job's angles.csv (``core.export``, model
    units), stored under ``jobs/<id>/exports/`` for the archive."""
    with tempfile.TemporaryDirectory() as tmp:
        angles = Path(tmp) / "angles.csv"
        angles.write_text(angles_csv)
        for path in export(Path(tmp), list(EXPORT_FILES), read_angles_csv(angles), model):
            storage.put(f"jobs/{job_id}/exports/{path.name}", [path.read_bytes()])


def _join_detections(session: Session, storage: Storage, job_id: int) -> None:
    """detections.csv of the whole job: the header, then the chunks' rows in chunk order,
    copied block by block. A chunk fitted by a worker older than this file has none: then
    the job has no detections.csv."""
    indices = session.scalars(select(Chunk.index).where(Chunk.job_id == job_id).order_by(Chunk.index)).all()
    keys = [f"jobs/{job_id}/chunks/{i}.detections.csv" for i in indices]
    if not all(storage.exists(k) for k in keys):
        logger.warning("job %s: a chunk has no detections; no detections.csv", job_id)
        return
    with storage.writer(f"jobs/{job_id}/exports/{DETECTIONS_FILE}") as out:
        out.write((",".join(DETECTIONS_HEADER) + "\n").encode())
        for key in keys:
            with storage.open(key) as src:
                shutil.copyfileobj(src, out)


def _outputs(session: Session, loaded: _Loaded, result: SequenceResult, fits: list[ImageFit]) -> Outputs:
    """``core.pipeline.outputs`` of the distributed run, the report with what only the service knows."""
    job = loaded.job
    seconds = ((utcnow() - _aware(job.started_at)).total_seconds() if job.started_at else 0.0)
    workers = session.scalars(select(Chunk.worker).where(Chunk.job_id == job.id).distinct()).all()
    results = outputs(loaded.fit, FitOutcome(result, seconds, max(len(workers), 1)))
    report = results.report
    report["videos"] = [  # as the lab knows them, never server paths or storage keys
        {"id": v.id, "filename": v.filename, "name": v.name, "metadata": v.meta, "frames": v.frames,
         "announced_frames": v.announced_frames, "warning": missing_frames(v)}
        for v in _videos(session, job.id)]
    report.update(_labels(session, job))
    report["service"] = {"job_id": job.id, "chunks": job.chunks_total, "workers": sorted(workers),
                         "histogram_version_id": job.histogram_version_id,
                         "attempts_total": sum(f.attempts for f in fits)}
    return results


def _labels(session: Session, job: Job) -> dict[str, Any]:
    """The lab's ids, names and metadata of the job, its batch (if any), model and rig."""
    model, rig = session.get_one(Model, job.model_id), session.get_one(RigRow, job.rig_id)
    batch = None if job.batch_id is None else session.get_one(Batch, job.batch_id)
    return {
        "job": {"id": job.id, "name": job.name, "metadata": job.meta, "trial": job.trial},
        "batch": None if batch is None else {"id": batch.id, "name": batch.name, "metadata": batch.meta},
        "model": {"id": model.id, "name": model.name, "metadata": model.meta},
        "rig": {"id": rig.id, "name": rig.name, "metadata": rig.meta},
    }


# ---- failures -----------------------------------------------------------------------------------
def fail_chunk(chunk_id: int, message: str) -> None:
    """Record a chunk's failure; its job fails with the message."""
    with session_scope() as session:
        chunk = session.get_one(Chunk, chunk_id)
        chunk.status, chunk.error = ChunkStatus.FAILED, message
        job_id, where = chunk.job_id, f"chunk {chunk.index} (images {chunk.first}-{chunk.last - 1})"
    fail_job(job_id, f"{where} failed: {message}")


def fail_job(job_id: int, message: str) -> None:
    """Mark a job failed with ``message`` unless it has already ended; the message names the
    job's videos by id and upload name, never by server path or storage key."""
    root = get_storage().root
    with session_scope() as session:
        message = redact(message, video_names(_videos(session, job_id), root), root)
        session.execute(update(Job).where(Job.id == job_id, Job.status.not_in(list(TERMINAL)))
                        .values(status=JobStatus.FAILED, error=message, finished_at=utcnow()))


def _set_chunk(chunk_id: int, status: ChunkStatus) -> None:
    with session_scope() as session:
        session.execute(update(Chunk).where(Chunk.id == chunk_id).values(status=status))


# ---- rows ---------------------------------------------------------------------------------------
def _videos(session: Session, job_id: int) -> list[Video]:
    """The job's videos in the rig's order."""
    return list(session.scalars(select(Video).join(JobVideo, JobVideo.video_id == Video.id)
                                .where(JobVideo.job_id == job_id).order_by(JobVideo.position)))


def _fits(session: Session, job_id: int) -> list[ImageFit]:
    records = session.scalars(select(ImageResult.record).where(ImageResult.job_id == job_id)
                              .order_by(ImageResult.sample)).all()
    return [ImageFit.from_record(r) for r in records]


def _image_row(job_id: int, fit: ImageFit) -> dict[str, Any]:
    record = fit.to_record()
    return {"job_id": job_id, "sample": fit.sample, "attempts": fit.attempts,
            "status": fit.status.value, "error_px": record["error"], "record": record}


def _attempt_row(job_id: int, fit: ImageFit, worker: str) -> dict[str, Any]:
    record = fit.to_record()
    return {"job_id": job_id, "sample": fit.sample, "attempt": max(fit.attempts, 1),
            "error_px": record["error"], "objective": record["objective"], "worker": worker}


def _insert_ignore(session: Session, table: type[ImageResult] | type[Attempt],
                   rows: Iterable[dict[str, Any]]) -> None:
    """INSERT … ON CONFLICT DO NOTHING on the table's unique key (a redelivered task's rows)."""
    rows = list(rows)
    dialect = postgresql if session.get_bind().dialect.name == "postgresql" else sqlite
    for start in range(0, len(rows), _INSERT_BATCH):
        batch = rows[start:start + _INSERT_BATCH]
        session.execute(dialect.insert(table).values(batch).on_conflict_do_nothing())


def _aware(moment: Any) -> Any:
    """SQLite returns naive datetimes for timezone-aware columns: they were stored in UTC."""
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)
