"""Per-lab limits that protect the service, computed from existing rows (no counters to drift).

- uploads in the last hour, in files and bytes, from ``videos.created_at`` and ``size_bytes``;
- active (queued, running or re-analysing) jobs, from ``jobs.status``;
- frames per job, from the videos' probed frame counts;
- the work of one image, estimated from the model's and the rig's sizes (``core.cost``).

Checks that admit new rows run with the lab's row locked (``SELECT … FOR UPDATE`` on
PostgreSQL; SQLite's ``BEGIN IMMEDIATE`` already serialises writers), so concurrent
requests of one lab cannot both pass the last free place.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from core.cost import FitCostError, check_fit_cost, estimate_fit_cost
from core.fit import FitParams
from core.model import KinematicModel
from core.rig import Rig
from service.errors import InvalidError, RateLimitedError
from service.models import TERMINAL, Job, Lab, Model, Video, utcnow
from service.settings import Settings

logger = logging.getLogger(__name__)

WINDOW = timedelta(hours=1)
# Active jobs end at no predictable time: a client over the cap is told to come back in a minute.
ACTIVE_JOBS_RETRY_S = 60


def lock_lab(session: Session, lab: Lab) -> None:
    """Serialise this lab's admitting transactions until commit."""
    session.execute(select(Lab.id).where(Lab.id == lab.id).with_for_update())


def check_upload(session: Session, lab: Lab, settings: Settings, incoming: int) -> None:
    """429 if ``incoming`` more bytes (one more file) would pass the lab's hourly upload limits.

    Called before streaming (with the declared length, 0 if unknown) to refuse early, and
    again before registering (with the real size, lab locked) to be exact.
    """
    since = utcnow() - WINDOW
    files, used, oldest = session.execute(
        select(func.count(), func.coalesce(func.sum(Video.size_bytes), 0), func.min(Video.created_at))
        .where(Video.lab_id == lab.id, Video.created_at > since)
    ).one()
    if files + 1 > settings.upload_files_per_hour:
        _refuse(lab, f"this lab uploaded {files} videos in the last hour; at most "
                f"{settings.upload_files_per_hour} per hour (MOCAP_UPLOAD_FILES_PER_HOUR)",
                _until_out_of_window(oldest))
    if used + incoming > settings.upload_bytes_per_hour:
        _refuse(lab, f"this lab uploaded {used} bytes in the last hour, this upload is {incoming}; at "
                f"most {settings.upload_bytes_per_hour} bytes per hour (MOCAP_UPLOAD_BYTES_PER_HOUR)",
                _until_out_of_window(oldest))


def check_active_jobs(session: Session, lab: Lab, settings: Settings, new: int) -> None:
    """429 if ``new`` more jobs would pass the lab's cap on queued + running jobs."""
    active = session.scalar(select(func.count()).where(Job.lab_id == lab.id,
                                                       Job.status.not_in(list(TERMINAL)))) or 0
    if active + new > settings.max_active_jobs_per_lab:
        _refuse(lab, f"this lab has {active} queued or running jobs and submits {new}; at most "
                f"{settings.max_active_jobs_per_lab} at once (MOCAP_MAX_ACTIVE_JOBS_PER_LAB)",
                ACTIVE_JOBS_RETRY_S)


def check_frames(videos: Sequence[Video], settings: Settings) -> None:
    """422 if a job's videos hold more frames than one job may fit (the shortest video counts,
    as in ``core.video.VideoSet``)."""
    frames = min(v.frames for v in videos)
    if frames > settings.max_frames_per_job:
        raise InvalidError(f"the job's videos hold {frames} frames; this server fits at most "
                           f"{settings.max_frames_per_job} per job (MOCAP_MAX_FRAMES_PER_JOB): "
                           "split the trial")


def check_cost(model: Model, rig: Rig, params: FitParams, videos: Sequence[Video], fields_per_frame: int,
               settings: Settings) -> None:
    """422 if one attempt on one image is estimated to outlast a chunk task's time limit (one
    image must fit in a task), or to need more memory than a worker should give it."""
    kinematic = _kinematic(model.xml)
    images = min(v.frames for v in videos) * fields_per_frame
    try:
        check_fit_cost(estimate_fit_cost(kinematic, rig, params, images=images),
                       max_attempt_s=settings.task_soft_time_limit_s,
                       time_limit_name="a chunk task's time limit, MOCAP_TASK_SOFT_TIME_LIMIT_S")
    except FitCostError as exc:
        k = kinematic
        sizes = f"{len(k.joints)} joints, {len(k.markers)} markers, {len(k.dofs)} DOFs"
        raise InvalidError(f"model {model.id} ({sizes}) with {len(rig.views)} view(s): {exc}") from None


@functools.lru_cache(maxsize=8)
def _kinematic(xml: str) -> KinematicModel:
    """A stored model parsed once per process: a batch checks it for each of its trials."""
    return KinematicModel.from_xml(xml)


def _refuse(lab: Lab, message: str, retry_after: int) -> None:
    """Log (an operator sees which lab pushes the limits) and raise the 429."""
    logger.info("lab %s refused: %s", lab.id, message)
    raise RateLimitedError(message, retry_after)


def _until_out_of_window(oldest: datetime | None) -> int:
    """Seconds until the oldest upload of the window leaves it (a place frees up then)."""
    if oldest is None:
        return 1
    oldest = oldest if oldest.tzinfo else oldest.replace(tzinfo=UTC)  # SQLite: naive UTC
    return math.ceil((oldest + WINDOW - utcnow()).total_seconds())
