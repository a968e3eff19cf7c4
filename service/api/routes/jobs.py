"""Fitting jobs: submit (202), poll, list, cancel, download results."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator

from fastapi import APIRouter, Response
from fastapi.responses import FileResponse, StreamingResponse
from kombu.exceptions import OperationalError
from sqlalchemy.orm import Session

from core.export import DETECTIONS_FILE, EXPORT_FILES
from service import artifacts, crud, examples
from service.api.deps import CurrentLab, Cursor, Limit, PathId, SessionDep, SettingsDep, StorageDep
from service.archive import stream_zip
from service.errors import NotFoundError, QueueUnavailableError
from service.models import Job, JobStatus, Lab, Model, RigRow
from service.schemas import JobCreate, JobPage, JobPublic, Progress
from service.storage import Storage
from worker.celery_app import PLAN_JOB
from worker.celery_app import app as celery

logger = logging.getLogger(__name__)

router = APIRouter(prefix="/jobs", tags=["jobs"])

RESULTS = {"angles.csv": "text/csv", "histograms.xml": "application/xml",
           "report.json": "application/json"}
RESULT_EXAMPLES = {"report.json": {"example": examples.REPORT}}
RESULT_DOCS = {
    "angles.csv": "The fitted angles of every image (FORMATS §3), as `mocap fit` writes them.",
    "histograms.xml": "The histograms after this job (FORMATS §4): its prior with its observations.",
    "report.json": "Error statistics, re-analyses, detections and settings, and the job's, batch's, "
                   "model's, rig's and videos' ids, names and metadata (upload names, never storage "
                   "keys or server paths).",
}


def job_public(job: Job) -> JobPublic:
    """A job as the API shows it: every field from the job row alone (a poll is one read)."""
    return JobPublic(
        id=job.id, status=job.status, model_id=job.model_id, rig_id=job.rig_id, batch_id=job.batch_id,
        trial=job.trial, name=job.name, metadata=job.meta, histogram_version_id=job.histogram_version_id,
        options=job.options, progress=progress(job), error=job.error, created_at=job.created_at,
        started_at=job.started_at, fitted_at=job.fitted_at, finished_at=job.finished_at,
    )


def progress(job: Job) -> Progress:
    return Progress(images_total=job.images_total, images_done=job.images_done,
                    images_over_threshold=job.images_over_threshold,
                    reanalyses_pending=job.reanalyses_pending, chunks_total=job.chunks_total,
                    chunks_done=job.chunks_done)


# A few quick retries, then 503: an unreachable broker must not hold the request for long.
PUBLISH_RETRY = {"max_retries": 2, "interval_start": 0.2, "interval_step": 0.5, "interval_max": 1.0}


def enqueue(session: Session, jobs: list[Job]) -> None:
    """Queue committed jobs' planning tasks (ids only: the worker reads the rest from the DB).

    If the broker cannot be reached, the jobs not yet queued are failed with a message
    saying so (and the request is 503) rather than left ``queued`` with no task to run them.
    """
    for i, job in enumerate(jobs):
        try:
            celery.send_task(PLAN_JOB, args=[job.id], retry=True, retry_policy=PUBLISH_RETRY)
        except OperationalError as exc:
            logger.exception("cannot queue job %s", job.id)
            message = "the job queue (broker) is unreachable; the job was not started, submit it again"
            crud.fail_unqueued(session, jobs[i:], message)
            raise QueueUnavailableError(message) from exc


@router.post("", status_code=202, response_model=JobPublic,
             summary="Submit a job; poll the Location it returns")
def submit(body: JobCreate, response: Response, session: SessionDep, settings: SettingsDep,
           lab: CurrentLab) -> JobPublic:
    """Submit a fitting job (202): model, rig, one video per camera of the rig, options as
    ``mocap fit`` takes them, and an optional ``name`` and ``metadata`` carried into report.json.
    Poll the ``Location`` it returns. Example: ``POST /v1/jobs`` with
    ``{"model_id": 1, "rig_id": 1, "video_ids": [1], "name": "walk-07"}``"""
    job = crud.submit_job(session, lab, settings, body)
    enqueue(session, [job])
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    return job_public(job)


@router.get("", response_model=JobPage, summary="The lab's jobs, newest first")
def list_jobs(session: SessionDep, lab: CurrentLab, status: JobStatus | None = None,
              cursor: Cursor = None, limit: Limit = 50) -> JobPage:
    """The lab's jobs, newest first, optionally of one ``status``, ``limit`` per page; pass
    ``next_cursor`` as ``?cursor=`` for the next page. Example: ``GET /v1/jobs?status=running``"""
    rows, next_cursor = crud.list_jobs(session, lab, status=status, cursor=cursor, limit=limit)
    return JobPage(items=[job_public(j) for j in rows], next_cursor=next_cursor)


@router.get("/{job_id}", response_model=JobPublic)
def get_job(job_id: PathId, session: SessionDep, lab: CurrentLab) -> JobPublic:
    """One job: status, progress counters, options, name and metadata (one row read: poll it).
    Example: ``GET /v1/jobs/7``"""
    return job_public(crud.owned(session, Job, job_id, lab))


@router.post("/{job_id}/cancel", response_model=JobPublic,
             summary="Cancel a job; workers stop between images")
def cancel(job_id: PathId, session: SessionDep, lab: CurrentLab) -> JobPublic:
    """Cancel a job that has not ended: queued chunks are dropped, running ones stop between
    images; an ended job is returned unchanged. Example: ``POST /v1/jobs/7/cancel``"""
    return job_public(crud.cancel_job(session, lab, job_id))


def _result(name: str):  # type: ignore[no-untyped-def]
    def download(job_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> FileResponse:
        key = crud.result_key(session, lab, job_id, name)
        return FileResponse(storage.path(key), media_type=RESULTS[name], filename=f"job-{job_id}-{name}")

    download.__name__ = f"download_{name.replace('.', '_')}"
    return download


for _name in RESULTS:
    router.add_api_route(f"/{{job_id}}/{_name}", _result(_name), methods=["GET"], response_class=FileResponse,
                         summary=f"Download {_name} of a succeeded job (409 before)",
                         responses={200: {"content": {RESULTS[_name]: RESULT_EXAMPLES.get(_name, {})}}},
                         description=f"{RESULT_DOCS[_name]} 409 until the job has succeeded. Example: "
                                     f"``curl -H \"$H\" -O $API/jobs/7/{_name}``")


@router.get("/{job_id}/archive.zip", response_class=StreamingResponse,
            responses={200: {"content": {"application/zip": {}}}},
            summary="angles.csv, histograms.xml, report.json, angles.mot, markers.trc, markers.c3d, "
                    "detections.csv, model.xml, rig.json and the artifacts in one zip")
def archive(job_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> StreamingResponse:
    """Every result of a succeeded job in one zip, streamed: angles.csv, histograms.xml,
    report.json, the exports (angles.mot, markers.trc, markers.c3d, detections.csv), the model.xml
    and rig.json it used, and its artifacts. 409 before it has succeeded. Example:
    ``curl -H "$H" -o job-7.zip $API/jobs/7/archive.zip``"""
    entries = list(job_entries(session, storage, lab, job_id, folder=""))
    return StreamingResponse(stream_zip(entries), media_type="application/zip",
                             headers={"Content-Disposition": f'attachment; filename="job-{job_id}.zip"'})


def job_entries(session: Session, storage: Storage, lab: Lab, job_id: int,
                folder: str) -> Iterator[tuple[str, Storage, str] | tuple[str, bytes]]:
    """A succeeded job's results and the model and rig it used, as zip entries under ``folder``."""
    for name in RESULTS:
        yield f"{folder}{name}", storage, crud.result_key(session, lab, job_id, name)
    for name in [*EXPORT_FILES.values(), DETECTIONS_FILE]:  # jobs older than exports have none
        key = f"jobs/{job_id}/exports/{name}"
        if storage.exists(key):
            yield f"{folder}{name}", storage, key
    job = crud.owned(session, Job, job_id, lab)
    yield f"{folder}model.xml", session.get_one(Model, job.model_id).xml.encode()
    rig = session.get_one(RigRow, job.rig_id).spec
    yield f"{folder}rig.json", (json.dumps(rig, indent=2) + "\n").encode()
    for name in artifacts.listed(storage, job_id):
        yield f"{folder}{name}", storage, f"jobs/{job_id}/{name}"


# ---- seeing the fit: the artifacts options.overlay and options.plots ask for (service/artifacts.py)


@router.get("/{job_id}/artifacts", response_model=list[str],
            responses={200: {"content": {"application/json": {"example": examples.ARTIFACTS}}}},
            summary="Names of a succeeded job's overlay and plot files (empty unless its options asked)")
def list_artifacts(job_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> list[str]:
    """Names of a succeeded job's overlay and plot files (empty unless its options asked for
    them). Example: ``GET /v1/jobs/7/artifacts``"""
    crud.result_key(session, lab, job_id, artifacts.INDEX)  # 404 another lab's, 409 before success
    return artifacts.listed(storage, job_id)


@router.get("/{job_id}/artifacts/{name:path}", response_class=FileResponse,
            summary="Download one artifact, e.g. overlay/contact_sheet.png or plots/angles.svg")
def download_artifact(job_id: PathId, name: str, session: SessionDep, storage: StorageDep,
                      lab: CurrentLab) -> FileResponse:
    """One artifact of a succeeded job, by a name ``GET /v1/jobs/{id}/artifacts`` lists. Example:
    ``GET /v1/jobs/7/artifacts/plots/angles.svg``"""
    key = crud.result_key(session, lab, job_id, name)
    if not artifacts.NAME.match(name) or name not in artifacts.listed(storage, job_id):
        raise NotFoundError(f"job {job_id} has no artifact {name!r}: GET /v1/jobs/{job_id}/artifacts "
                            "lists them (submit with options.overlay or options.plots)")
    suffix = name[name.rfind("."):]
    headers = {"Content-Security-Policy": "default-src 'none'; style-src 'unsafe-inline'"}
    return FileResponse(storage.path(key), media_type=artifacts.MEDIA_TYPES[suffix], headers=headers,
                        filename=f"job-{job_id}-{name.replace('/', '-')}",
                        content_disposition_type="attachment" if suffix == ".avi" else "inline")
