"""The job queue: task names, the Celery app configured from ``service.settings``, one ``enqueue``.

The API and the worker both send tasks through :func:`enqueue`, by name (Celery ``send_task``), so
the API never imports ``worker``; ``worker.celery_app`` takes :func:`celery_app` and registers the
tasks (``worker.tasks``) under these names. Messages carry ids only: the database is the truth, and
a task is sent only after the transaction that needs it commits.

Settings and why:

- ``task_acks_late=True`` + ``task_reject_on_worker_lost=True``: a message is
  acknowledged only after its task returns, so a worker that dies mid-chunk
  (OOM, SIGKILL, lost machine) leaves the message to be delivered again rather
  than losing the chunk. Tasks are idempotent (keyed upserts, guarded state
  transitions in the database), so a second delivery changes nothing.
- ``worker_prefetch_multiplier=1``: a chunk takes seconds to minutes; a worker
  holding several reserved messages would starve idle workers (and with late
  acks those messages wait behind the running one).
- ``task_soft_time_limit < task_time_limit < visibility_timeout``: Redis
  re-delivers an unacknowledged message after the visibility timeout; if a task
  could run longer than that, a healthy chunk would be fitted twice at once. The
  soft limit raises inside the task (recorded as its failure), the hard limit
  kills a stuck process, both before Redis would hand the message to another.
- ``task_ignore_result=True``: results go to the database (image rows, chunk
  counts), the source of truth the API reads; a result backend would be a second,
  unbounded copy nobody reads.
- Embedded mode (``filesystem://``): kombu's filesystem transport in
  ``MOCAP_DATA_DIR/broker``, polled every ``MOCAP_FILESYSTEM_POLL_S``, each message
  written whole before it appears in the queue (``service.fs_broker``); it has no
  broadcast, so remote control (used by ``celery inspect`` and flower) is off there.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache
from typing import Any

from celery import Celery

from service.settings import Settings, get_settings

PLAN_JOB = "mocap.plan_job"
FIT_CHUNK = "mocap.fit_chunk"
REANALYSE_IMAGE = "mocap.reanalyse_image"
RESUME_JOB = "mocap.resume_job"


def make_celery(settings: Settings) -> Celery:
    """A Celery app for ``settings`` (broker, queue, limits), with no tasks of its own."""
    app = Celery("mocap", broker=settings.broker_url)
    transport: dict[str, Any] = {"visibility_timeout": settings.visibility_timeout_s}
    embedded = settings.broker_url.startswith("filesystem")
    if embedded:
        folder = settings.broker_dir.resolve()
        for sub in ("queue", "processed", "control", "incoming"):
            (folder / sub).mkdir(parents=True, exist_ok=True)
        # control_folder: kombu's exchange table, else ./control in whatever directory runs us.
        transport |= {"data_folder_in": str(folder / "queue"), "data_folder_out": str(folder / "queue"),
                      "processed_folder": str(folder / "processed"), "store_processed": False,
                      "control_folder": str(folder / "control"), "incoming_folder": str(folder / "incoming"),
                      "polling_interval": settings.filesystem_poll_s}
    app.conf.update(
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_soft_time_limit=settings.task_soft_time_limit_s,
        task_time_limit=settings.task_time_limit_s,
        broker_transport_options=transport,
        task_ignore_result=True,
        task_default_queue=settings.queue,
        task_serializer="json",
        accept_content=["json"],
        broker_connection_retry_on_startup=True,
        broker_transport="service.fs_broker:Transport" if embedded else None,
        worker_enable_remote_control=not embedded,
        worker_send_task_events=not embedded,  # flower's live view (Redis)
        task_send_sent_event=not embedded,
    )
    return app


@cache
def celery_app() -> Celery:
    """The process's Celery app, for the settings of its first use: one connection pool per
    process, shared by the API's, the worker's and the reaper's messages."""
    return make_celery(get_settings())


def enqueue(name: str, *args: int, retry_policy: Mapping[str, float] | None = None) -> None:
    """Send task ``name`` with ``args`` (ids only) to the settings' queue.

    ``retry_policy`` (kombu's ``max_retries``, ``interval_start``, ``interval_step``,
    ``interval_max``) bounds the retries of an unreachable broker, after which kombu's
    ``OperationalError`` is raised; without it Celery's default policy applies.
    """
    if retry_policy is None:
        celery_app().send_task(name, args=list(args))
    else:
        celery_app().send_task(name, args=list(args), retry=True, retry_policy=dict(retry_policy))
