"""Celery tasks: ids in, ``worker.orchestration`` does the work, failures recorded and re-raised.

Each task is idempotent (the orchestration guards every state change in the
database), so a message delivered twice changes nothing. A failure caused by the lab's
files (core's ModelError, RigError, HistogramError, VideoError) is the lab's to fix: logged
in one line and declared in ``throws`` (Celery logs it "raised expected", without a
traceback); anything else is the operator's, logged with its traceback.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from celery import Task
from celery.exceptions import SoftTimeLimitExceeded

from core.histogram import HistogramError
from core.model import ModelError
from core.rig import RigError
from core.video import VideoError
from service.broker import FIT_CHUNK, PLAN_JOB, REANALYSE_IMAGE, RESUME_JOB
from worker import orchestration
from worker.celery_app import app

logger = logging.getLogger(__name__)

USER_ERRORS = (ModelError, RigError, HistogramError, VideoError)


@contextmanager
def _recorded(what: str, record: Callable[[str], None]) -> Iterator[None]:
    """Log a failure, write its message to the database, and re-raise it."""
    try:
        yield
    except USER_ERRORS as exc:
        logger.info("%s failed on the lab's input: %s", what, exc)
        record(_describe(exc))
        raise
    except Exception as exc:
        logger.exception("%s failed", what)
        record(_describe(exc))
        raise


def _describe(exc: Exception) -> str:
    """The failure as the job's error: Celery's soft time limit says nothing by itself, and when
    its signal lands inside a numba kernel it surfaces as a SystemError caused by it."""
    if _caused_by(exc, SoftTimeLimitExceeded):
        limit = app.conf.task_soft_time_limit
        return (f"the task ran longer than its time limit of {limit} s (MOCAP_TASK_SOFT_TIME_LIMIT_S); "
                "submit smaller chunks (options.chunk_size)")
    return f"{type(exc).__name__}: {exc}"


def _caused_by(exc: BaseException | None, kind: type[BaseException]) -> bool:
    while exc is not None:
        if isinstance(exc, kind):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


@app.task(bind=True, name=PLAN_JOB, throws=USER_ERRORS)  # type: ignore[untyped-decorator]  # Celery has no types
def plan_job(self: Task, job_id: int) -> None:
    """Count the job's images and queue one task per chunk."""
    job_id = int(job_id)
    with _recorded(f"planning job {job_id}", lambda msg: orchestration.fail_job(job_id, msg)):
        orchestration.plan_job(job_id)


@app.task(bind=True, name=FIT_CHUNK, throws=USER_ERRORS)  # type: ignore[untyped-decorator]  # Celery has no types
def fit_chunk(self: Task, chunk_id: int) -> None:
    """Fit one chunk; the last chunk of a job merges and starts re-analysis."""
    chunk_id = int(chunk_id)
    with _recorded(f"chunk {chunk_id}", lambda msg: orchestration.fail_chunk(chunk_id, msg)):
        orchestration.run_chunk(chunk_id, worker=self.request.hostname or "")


@app.task(bind=True, name=RESUME_JOB, throws=USER_ERRORS)  # type: ignore[untyped-decorator]  # Celery has no types
def resume_job(self: Task, job_id: int) -> None:
    """Merge or finish a job whose worker died between its last step and the next (reaper)."""
    job_id = int(job_id)
    with _recorded(f"resuming job {job_id}", lambda msg: orchestration.fail_job(job_id, msg)):
        orchestration.resume(job_id)


@app.task(bind=True, name=REANALYSE_IMAGE, throws=USER_ERRORS)  # type: ignore[untyped-decorator]  # Celery has no types
def reanalyse_image(self: Task, job_id: int, sample: int, attempt: int) -> None:
    """One more attempt on one image; the last one pending finishes the job."""
    job_id = int(job_id)
    with _recorded(f"job {job_id} image {sample}", lambda msg: orchestration.fail_job(job_id, msg)):
        orchestration.run_attempt(job_id, int(sample), int(attempt), worker=self.request.hostname or "")
