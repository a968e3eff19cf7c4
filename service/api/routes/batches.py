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
    batch, jobs = crud.submit_batch(session, lab, settings, body)
    enqueue(session, jobs)
    response.headers["Location"] = f"/v1/batches/{batch.id}"
    return _public(batch, jobs)


@router.get("/{batch_id}", response_model=BatchPublic)
def get_batch(batch_id: PathId, session: SessionDep, lab: CurrentLab) -> BatchPublic:
    batch = crud.owned(session, Batch, batch_id, lab)
    return _public(batch, crud.batch_jobs(session, batch))


@router.get("/{batch_id}/archive.zip", response_class=StreamingResponse,
            summary="Every trial's results in its own folder (409 until all have succeeded)")
def archive(batch_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> StreamingResponse:
    batch = crud.owned(session, Batch, batch_id, lab)
    entries = [
        entry for job in crud.batch_jobs(session, batch)
        for entry in job_entries(session, storage, lab, job.id, folder=trial_folder(job))
    ]
    return StreamingResponse(stream_zip(entries), media_type="application/zip",
                             headers={"Content-Disposition": f'attachment; filename="batch-{batch_id}.zip"'})
