"""Camera rigs (FORMATS §2)."""

from __future__ import annotations

import json

from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool

from core.rig import Rig
from service import crud
from service.api.deps import CurrentLab, Cursor, Limit, PathId, SessionDep
from service.errors import InvalidError
from service.models import RigRow
from service.schemas import RigPage, RigPublic
from service.upload import read_document

router = APIRouter(prefix="/rigs", tags=["rigs"])

DOCUMENT_LIMIT = 1024**2


def _public(row: RigRow) -> RigPublic:
    rig = Rig.from_dict(row.spec)
    return RigPublic(id=row.id, views=[v.name for v in rig.views], videos=rig.n_videos,
                     created_at=row.created_at)


@router.post("", status_code=201, response_model=RigPublic,
             summary="Upload a rig.json (raw JSON body or multipart field 'file')")
async def create_rig(request: Request, session: SessionDep, lab: CurrentLab) -> RigPublic:
    raw = await read_document(request, DOCUMENT_LIMIT)
    try:
        spec = json.loads(raw, parse_constant=_no_constants)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InvalidError(f"rig is not valid JSON: {exc}") from None
    row = await run_in_threadpool(crud.create_rig, session, lab, spec)
    return _public(row)


@router.get("", response_model=RigPage, summary="The lab's rigs, newest first")
def list_rigs(session: SessionDep, lab: CurrentLab, cursor: Cursor = None, limit: Limit = 50) -> RigPage:
    rows, next_cursor = crud.list_owned(session, RigRow, lab, cursor=cursor, limit=limit)
    return RigPage(items=[_public(row) for row in rows], next_cursor=next_cursor)


@router.get("/{rig_id}", response_model=RigPublic)
def get_rig(rig_id: PathId, session: SessionDep, lab: CurrentLab) -> RigPublic:
    return _public(crud.owned(session, RigRow, rig_id, lab))


def _no_constants(name: str) -> float:
    raise InvalidError(f"rig JSON contains {name}, which is not a number")
