"""Camera rigs (FORMATS §2)."""

from __future__ import annotations

import json
from typing import Any

from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool

from core.rig import Rig
from service import crud
from service.api.deps import CurrentLab, PathId, SessionDep
from service.errors import InvalidError
from service.models import RigRow
from service.schemas import RigPublic
from service.upload import read_document

router = APIRouter(prefix="/rigs", tags=["rigs"])

DOCUMENT_LIMIT = 1024**2
# A rig nests 5 levels (views, a view, its projection, matrix rows, numbers); keys beside them are
# kept as uploaded and written back in archives, whose JSON encoder recurses per level.
MAX_DEPTH = 32


def _public(row: RigRow) -> RigPublic:
    rig = Rig.from_dict(row.spec)
    return RigPublic(id=row.id, views=[v.name for v in rig.views], videos=rig.n_videos)


@router.post("", status_code=201, response_model=RigPublic,
             summary="Upload a rig.json (raw JSON body or multipart field 'file')")
async def create_rig(request: Request, session: SessionDep, lab: CurrentLab) -> RigPublic:
    raw = await read_document(request, DOCUMENT_LIMIT)
    try:
        spec = json.loads(raw, parse_constant=_no_constants)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InvalidError(f"rig is not valid JSON: {exc}") from None
    except RecursionError:  # json's decoder recurses per level: 50,000 '[' would be a 500
        raise InvalidError("rig JSON is nested too deeply (a rig file nests a few levels)") from None
    if (depth := _depth(spec)) > MAX_DEPTH:
        raise InvalidError(f"rig JSON nests {depth} levels deep; a rig nests at most {MAX_DEPTH}")
    row = await run_in_threadpool(crud.create_rig, session, lab, spec)
    return _public(row)


@router.get("/{rig_id}", response_model=RigPublic)
def get_rig(rig_id: PathId, session: SessionDep, lab: CurrentLab) -> RigPublic:
    return _public(crud.owned(session, RigRow, rig_id, lab))


def _no_constants(name: str) -> float:
    raise InvalidError(f"rig JSON contains {name}, which is not a number")


def _depth(value: Any) -> int:
    """Nesting depth of parsed JSON (a number: 0, ``[1]``: 1), without recursion."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        item, depth = stack.pop()
        deepest = max(deepest, depth)
        if isinstance(item, dict | list):
            stack.extend((child, depth + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest
