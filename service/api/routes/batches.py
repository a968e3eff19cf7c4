"""Batches: one job per trial, sharing model, rig and options; one archive with a folder per trial."""

from __future__ import annotations

from collections import Counter

from fastapi import APIRouter, Response
from fastapi.responses import StreamingResponse

from service import crud
from service.api.deps import CurrentLab, PathId, SessionDep, SettingsDep, StorageDep
from service.api.routes.jobs import enqueue, job_entries, job_public
from service.archive import stream_zip, trial_folder
from service.models import TERMINAL, Batch, Job, JobStatus
from service.schemas import BatchCreate, BatchPublic, Progress

router = APIRouter(prefix="/batches", tags=["batches"])


def _public(batch: Batch, jobs: list[Job]) -> BatchPublic:
    statuses = Counter(j.status for j in jobs)
    if any(j.status not in TERMINAL for j in jobs):
        status = "running"
    elif statuses[JobStatus.SUCCEEDED] == len(jobs):
        status = JobStatus.SUCCEEDED
    else:
        status = JobStatus.CANCELED if statuses[JobStatus.CANCELED] else JobStatus.FAILED
    fields = Progress.model_fields
    total = Progress(**{f: sum(getattr(j, f) for j in jobs) for f in fields})
    return BatchPublic(id=batch.id, name=batch.name, metadata=batch.meta, status=status,
                       statuses=dict(statuses), progress=total, jobs=[job_public(j) for j in jobs])


@router.post("", status_code=202, response_model=BatchPublic, summary="Submit one job per trial")
def submit(body: BatchCreate, response: Response, session: SessionDep, settings: SettingsDep,
           lab: CurrentLab) -> BatchPublic:
    """Submit one job per trial (202), all or none, sharing model, rig and options; the batch and
    each trial may have a ``name`` and ``metadata`` (carried into report.json; a trial's name also
    into its archive folder). Example: ``POST /v1/batches`` with
    ``{"model_id": 1, "rig_id": 1, "trials": [{"video_ids": [1], "name": "walk"}]}``"""
    batch, jobs = crud.submit_batch(session, lab, settings, body)
    enqueue(session, jobs)
    response.headers["Location"] = f"/v1/batches/{batch.id}"
    return _public(batch, jobs)


@router.get("/{batch_id}", response_model=BatchPublic)
def get_batch(batch_id: PathId, session: SessionDep, lab: CurrentLab) -> BatchPublic:
    """A batch: its overall status, status counts, summed progress and every job. Example:
    ``GET /v1/batches/3``"""
    batch = crud.owned(session, Batch, batch_id, lab)
    return _public(batch, crud.batch_jobs(session, batch))


@router.get("/{batch_id}/archive.zip", response_class=StreamingResponse,
            responses={200: {"content": {"application/zip": {}}}},
            summary="Every trial's results in its own folder (409 until all have succeeded)")
def archive(batch_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> StreamingResponse:
    """Every trial's results in a folder of its own, ``trial-000-job-7/`` or, for a named trial,
    ``trial-000-job-7-<name>/`` (the name reduced to letters, digits, ``._-``). 409 until every job
    has succeeded. Example: ``curl -H "$H" -o batch-3.zip $API/batches/3/archive.zip``"""
    batch = crud.owned(session, Batch, batch_id, lab)
    entries = [
        entry for job in crud.batch_jobs(session, batch)
        for entry in job_entries(session, storage, lab, job.id, folder=trial_folder(job))
    ]
    return StreamingResponse(stream_zip(entries), media_type="application/zip",
                             headers={"Content-Disposition": f'attachment; filename="batch-{batch_id}.zip"'})
