"""The reaper: sends again, from database state, the work whose worker or message was lost.

- A **running chunk whose heartbeat is stale** (older than ``MOCAP_HEARTBEAT_TIMEOUT_S``):
  its worker was killed as a whole (SIGKILL, lost machine), so Celery never handed its
  message back and Redis would re-deliver it only after the visibility timeout (an hour).
  It goes back to ``queued`` and is sent again.
- **Queued work whose message is gone** (broker flushed or restarted without persistence):
  a chunk queued, a job waiting to be planned, or a re-analysing job with no progress, for
  longer than ``MOCAP_QUEUED_TIMEOUT_S`` *while the broker's queue is empty*. The same
  holds for a job whose worker died between two steps (every chunk done but never merged,
  nothing pending but never finished): it gets a ``resume_job`` task. The empty
  queue is what tells a lost message from one that merely waits behind a long backlog;
  without it every waiting chunk would be sent again each timeout.

Each re-send is preceded by an UPDATE guarded by the very condition that selected it
(stale heartbeat, old ``queued_at`` / ``progress_at``) which also moves that clock: of two
reapers racing on one row, one changes it and sends, the other changes nothing and sends
nothing. A duplicate that still gets through (a message thought lost that was only slow)
is harmless: tasks are idempotent. Attempts are counted on the chunk row when a delivery
starts it (``worker.orchestration._claim``), which bounds a chunk that keeps killing its
worker to ``MOCAP_MAX_CHUNK_ATTEMPTS``.

Why a thread and not Celery beat: beat must run as exactly one process, one more thing to
deploy and to keep alive, and the reaper is only a few indexed queries every few seconds.
A daemon thread runs in every ``mocap worker`` (the Celery main process, which does not
fit chunks itself) and in ``mocap serve``; guarded UPDATEs make any number of them safe.
``mocap reap`` runs one pass, for cron.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from celery.signals import worker_process_init, worker_ready
from sqlalchemy import func, or_, select, update

from service import broker
from service.broker import FIT_CHUNK, PLAN_JOB, REANALYSE_IMAGE, RESUME_JOB
from service.db import get_engine, rows_changed, session_scope
from service.models import Chunk, ChunkStatus, Job, JobStatus, utcnow
from service.settings import get_settings
from worker.orchestration import pending_reanalyses

logger = logging.getLogger(__name__)


@dataclass
class Reaped:
    """What one pass sent again."""

    stale_chunks: list[int]
    lost_chunks: list[int]
    lost_plans: list[int]
    lost_reanalyses: int
    resumed: list[int]

    def __bool__(self) -> bool:
        return bool(self.stale_chunks or self.lost_chunks or self.lost_plans or self.lost_reanalyses
                    or self.resumed)


def reap() -> Reaped:
    """One pass: re-queue stale chunks always, lost queued work only while the queue is empty."""
    settings, now = get_settings(), utcnow()
    stale = now - timedelta(seconds=settings.heartbeat_timeout_s)
    old = now - timedelta(seconds=settings.queued_timeout_s)
    reaped = Reaped(_requeue_stale_chunks(stale, now), [], [], 0, [])
    if queue_length() == 0:
        reaped.lost_chunks = _requeue_lost_chunks(old, now)
        reaped.lost_plans = _requeue_lost_plans(old, now)
        reaped.lost_reanalyses, reaped.resumed = _requeue_lost_reanalyses(old, now)
        reaped.resumed += _resume_stalled_fan_in(old, now)
    if reaped:
        logger.warning("reaper sent again: %s", reaped)
    return reaped


def queue_length() -> int:
    """Messages waiting in the settings' queue. Declares exchange, queue and binding first:
    a FLUSHDB deletes them, and the messages this pass sends must have a route."""
    app = broker.celery_app()
    queue = app.amqp.queues[get_settings().queue]
    with app.connection_for_write() as connection:
        bound = queue.bind(connection.default_channel)
        bound.exchange.declare()
        waiting = bound.queue_declare().message_count
        bound.queue_bind()
    return int(waiting)


def _running_job() -> Any:
    return select(Job.id).where(Job.status == JobStatus.RUNNING)


def _requeue_stale_chunks(stale: datetime, now: datetime) -> list[int]:
    condition = (Chunk.status == ChunkStatus.RUNNING, Chunk.heartbeat_at < stale,
                 Chunk.job_id.in_(_running_job()))
    return _requeue_chunks(condition, now)


def _requeue_lost_chunks(old: datetime, now: datetime) -> list[int]:
    condition = (Chunk.status == ChunkStatus.QUEUED, or_(Chunk.queued_at.is_(None), Chunk.queued_at < old),
                 Chunk.job_id.in_(_running_job()))
    return _requeue_chunks(condition, now)


def _requeue_chunks(condition: tuple[Any, ...], now: datetime) -> list[int]:
    """Every chunk meeting ``condition`` that this reaper wins (guarded UPDATE), queued and sent."""
    sent = []
    with session_scope() as session:
        ids = session.scalars(select(Chunk.id).where(*condition)).all()
    for chunk_id in ids:
        with session_scope() as session:
            won = rows_changed(session, update(Chunk).where(Chunk.id == chunk_id, *condition)
                       .values(status=ChunkStatus.QUEUED, queued_at=now))
        if won:
            broker.enqueue(FIT_CHUNK, chunk_id)
            sent.append(chunk_id)
    return sent


def _requeue_lost_plans(old: datetime, now: datetime) -> list[int]:
    condition = (Job.status == JobStatus.QUEUED, Job.created_at < old,
                 or_(Job.progress_at.is_(None), Job.progress_at < old))
    sent = []
    for job_id in _won_jobs(condition, now):
        broker.enqueue(PLAN_JOB, job_id)
        sent.append(job_id)
    return sent


def _requeue_lost_reanalyses(old: datetime, now: datetime) -> tuple[int, list[int]]:
    """Re-analyses sent again, and the jobs with none left that were never finished."""
    condition = (Job.status == JobStatus.REANALYSING, or_(Job.progress_at.is_(None), Job.progress_at < old))
    sent, resumed = 0, []
    for job_id in _won_jobs(condition, now):
        with session_scope() as session:
            pending = pending_reanalyses(session, job_id)
        for sample, attempt in pending:
            broker.enqueue(REANALYSE_IMAGE, job_id, sample, attempt)
        sent += len(pending)
        if not pending:
            broker.enqueue(RESUME_JOB, job_id)
            resumed.append(job_id)
    return sent, resumed


def _resume_stalled_fan_in(old: datetime, now: datetime) -> list[int]:
    """Running jobs whose chunks are all done (the last one before ``old``), not yet moved on."""
    last_done = select(func.max(Chunk.heartbeat_at)).where(Chunk.job_id == Job.id).scalar_subquery()
    condition = (Job.status == JobStatus.RUNNING, Job.chunks_total > 0, Job.chunks_done == Job.chunks_total,
                 last_done < old, or_(Job.progress_at.is_(None), Job.progress_at < old))
    won = _won_jobs(condition, now)
    for job_id in won:
        broker.enqueue(RESUME_JOB, job_id)
    return won


def _won_jobs(condition: tuple[Any, ...], now: datetime) -> list[int]:
    """Jobs meeting ``condition`` whose ``progress_at`` this reaper moved to ``now``."""
    with session_scope() as session:
        ids = session.scalars(select(Job.id).where(*condition)).all()
    won = []
    for job_id in ids:
        with session_scope() as session:
            if rows_changed(session, update(Job).where(Job.id == job_id, *condition).values(progress_at=now)):
                won.append(job_id)
    return won


def start_reaper(interval_s: float | None = None) -> threading.Thread:
    """A daemon thread running :func:`reap` every ``interval_s`` (``MOCAP_REAP_INTERVAL_S``)."""
    interval = interval_s or get_settings().reap_interval_s

    def loop() -> None:
        while True:
            time.sleep(interval)
            try:
                reap()
            except Exception:  # a database or broker outage: try again next pass
                logger.exception("reaper pass failed")

    thread = threading.Thread(target=loop, name="mocap-reaper", daemon=True)
    thread.start()
    logger.info("reaper: every %.1f s", interval)
    return thread


@worker_ready.connect  # type: ignore[untyped-decorator]  # Celery has no types
def _start_in_worker(**_: Any) -> None:
    """In the Celery main process (which forks the pool, and fits nothing itself)."""
    start_reaper()


@worker_process_init.connect  # type: ignore[untyped-decorator]  # Celery has no types
def _fresh_connections(**_: Any) -> None:
    """A forked pool process must not share the main process's pooled database connections
    (the reaper's): SQLAlchemy's advice, drop them without closing the parent's sockets."""
    get_engine().dispose(close=False)
