"""worker.orchestration's steps, each run twice on one database: the second run changes nothing.

A redelivered message (Celery hands a task back when its worker dies; the reaper sends
lost ones again) runs a step a second time; these tests play that by hand, with the queue
replaced by the recorder of ``conftest.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from recorded_queue import CHUNK_SIZE, IMAGES, MISFIT, Recorder
from sqlalchemy import func, select

from service.broker import FIT_CHUNK, REANALYSE_IMAGE
from service.db import session_scope
from service.models import Attempt, Chunk, ChunkStatus, HistogramVersion, ImageResult, Job, JobStatus
from worker import orchestration

WORKER = "test-worker"


def _job(job_id: int) -> dict[str, Any]:
    with session_scope() as session:
        job = session.get_one(Job, job_id)
        return {c.name: getattr(job, c.name) for c in Job.__table__.columns}


def _count(table: type[Attempt] | type[ImageResult] | type[Chunk], job_id: int) -> int:
    with session_scope() as session:
        return session.scalar(select(func.count()).where(table.job_id == job_id)) or 0


def _archive_versions(job_id: int) -> int:
    """Versions of the histogram archive of the job's model."""
    with session_scope() as session:
        model_id = session.get_one(Job, job_id).model_id
        return session.scalar(select(func.count()).where(HistogramVersion.model_id == model_id)) or 0


def _run(name: str, args: tuple[int, ...]) -> None:
    """What worker.tasks does with a message."""
    if name == FIT_CHUNK:
        orchestration.run_chunk(*args, worker=WORKER)
    elif name == REANALYSE_IMAGE:
        orchestration.run_attempt(*args, worker=WORKER)
    else:
        raise AssertionError(f"unexpected message {name}{args}")


def _drain(queue: Recorder) -> int:
    """Run every message, and those they send, until none is left; the number run."""
    ran = 0
    while messages := queue.take():
        for name, args in messages:
            _run(name, args)
            ran += 1
    return ran


def _fit_all_chunks(queue: Recorder, job_id: int) -> list[tuple[str, tuple[int, ...]]]:
    """Plan the job and run its chunks; the messages the last chunk sent (re-analyses)."""
    orchestration.plan_job(job_id)
    for name, args in queue.take():
        _run(name, args)
    return queue.take()


def test_planning_twice_creates_the_chunks_once(queue: Recorder, job_id: int) -> None:
    orchestration.plan_job(job_id)
    first = queue.take()
    job = _job(job_id)
    orchestration.plan_job(job_id)
    assert queue.take() == []
    assert _job(job_id) == job
    assert job["status"] == JobStatus.RUNNING
    assert job["chunks_total"] == _count(Chunk, job_id) == IMAGES // CHUNK_SIZE
    with session_scope() as session:
        ids = session.scalars(select(Chunk.id).where(Chunk.job_id == job_id).order_by(Chunk.index)).all()
    assert first == [(FIT_CHUNK, (i,)) for i in ids]


def test_a_chunk_run_twice_is_counted_once(queue: Recorder, job_id: int) -> None:
    orchestration.plan_job(job_id)
    (_, (chunk_id,)), *_ = queue.take()
    orchestration.run_chunk(chunk_id, worker=WORKER)
    job = _job(job_id)
    assert (job["chunks_done"], job["images_done"]) == (1, CHUNK_SIZE)
    rows = (_count(ImageResult, job_id), _count(Attempt, job_id))
    assert rows == (CHUNK_SIZE, CHUNK_SIZE)

    orchestration.run_chunk(chunk_id, worker=WORKER)  # delivered again after it finished
    assert _job(job_id) == job
    assert (_count(ImageResult, job_id), _count(Attempt, job_id)) == rows
    with session_scope() as session:
        chunk = session.get_one(Chunk, chunk_id)
        assert (chunk.status, chunk.attempts) == (ChunkStatus.DONE, 1)


def test_a_chunk_finished_by_two_deliveries_is_counted_once(queue: Recorder, job_id: int) -> None:
    """The second delivery claimed the chunk before the first finished: both fit it, and the
    later completion stores nothing and counts nothing."""
    orchestration.plan_job(job_id)
    (_, (chunk_id,)), *_ = queue.take()
    orchestration.run_chunk(chunk_id, worker=WORKER)
    job = _job(job_id)
    with session_scope() as session:
        chunk = session.get_one(Chunk, chunk_id)
        key = chunk.observed_key
        fits = orchestration._fits(session, job_id)
    assert key is not None and len(fits) == CHUNK_SIZE
    assert not orchestration._complete_chunk(chunk_id, job_id, key, fits, "another-worker")
    assert _job(job_id) == job
    assert _count(Attempt, job_id) == CHUNK_SIZE


def test_the_last_chunk_queues_reanalysis_of_the_images_over_the_threshold(
    queue: Recorder, job_id: int
) -> None:
    sent = _fit_all_chunks(queue, job_id)
    assert sent == [(REANALYSE_IMAGE, (job_id, sample, 2)) for sample in MISFIT]
    with session_scope() as session:
        over = session.scalars(select(ImageResult.sample).where(
            ImageResult.job_id == job_id, ImageResult.status == "over_threshold")).all()
    assert sorted(over) == list(MISFIT)
    job = _job(job_id)
    assert (job["status"], job["reanalyses_pending"]) == (JobStatus.REANALYSING, len(MISFIT))
    assert job["images_over_threshold"] == len(MISFIT)


def test_merging_twice_queues_the_reanalysis_once(queue: Recorder, job_id: int) -> None:
    _fit_all_chunks(queue, job_id)
    job = _job(job_id)
    orchestration._after_chunks(job_id)
    orchestration.resume(job_id)
    assert queue.take() == []
    assert _job(job_id) == job


def test_a_reanalysis_delivered_twice_is_stored_once(queue: Recorder, job_id: int) -> None:
    _fit_all_chunks(queue, job_id)
    sample = MISFIT[0]
    orchestration.run_attempt(job_id, sample, 2, worker=WORKER)
    job, sent = _job(job_id), queue.take()
    attempts = _count(Attempt, job_id)
    assert attempts == IMAGES + 1
    orchestration.run_attempt(job_id, sample, 2, worker=WORKER)
    assert queue.take() == []
    assert _job(job_id) == job
    assert _count(Attempt, job_id) == attempts
    # max_attempts is 2: this image needs no third attempt, one re-analysis is left pending.
    assert sent == [] and job["reanalyses_pending"] == len(MISFIT) - 1


def test_the_reaper_finds_pending_reanalyses_by_the_rule_that_queued_them(
    queue: Recorder, job_id: int
) -> None:
    sent = _fit_all_chunks(queue, job_id)
    with session_scope() as session:
        pending = orchestration.pending_reanalyses(session, job_id)
    assert [(REANALYSE_IMAGE, (job_id, sample, attempt)) for sample, attempt in pending] == sent
    orchestration.run_attempt(job_id, MISFIT[0], 2, worker=WORKER)  # max_attempts 2: settled
    with session_scope() as session:
        assert orchestration.pending_reanalyses(session, job_id) == [(MISFIT[1], 2)]


def test_a_job_with_no_image_within_the_threshold_adds_no_archive_version(
        queue: Recorder, submit: Callable[..., int]) -> None:
    """Every image over a threshold no fit meets: the job succeeds, and the model's archive
    keeps its one version (a second would repeat it)."""
    job_id = submit(chunk_size=CHUNK_SIZE, marker_diameter_px=4.0, max_attempts=1, error_threshold_px=1e-9)
    orchestration.plan_job(job_id)
    _drain(queue)
    job = _job(job_id)
    assert job["status"] == JobStatus.SUCCEEDED and job["images_over_threshold"] == IMAGES
    assert _archive_versions(job_id) == 1


def test_a_job_finishes_exactly_once(queue: Recorder, job_id: int) -> None:
    orchestration.plan_job(job_id)
    assert _drain(queue) == IMAGES // CHUNK_SIZE + len(MISFIT)
    job = _job(job_id)
    assert job["status"] == JobStatus.SUCCEEDED
    assert (job["reanalyses_pending"], job["chunks_done"]) == (0, IMAGES // CHUNK_SIZE)
    assert _archive_versions(job_id) == 2  # the prior, then this job folded in

    orchestration._finish(job_id)
    orchestration.resume(job_id)
    orchestration.run_attempt(job_id, MISFIT[-1], 2, worker=WORKER)
    assert queue.take() == []
    assert _job(job_id) == job
    assert _archive_versions(job_id) == 2
