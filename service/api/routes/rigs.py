"""Camera rigs (FORMATS §2)."""

from __future__ import annotations

import json
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from core.calibration import import_rig
from core.rig import MAX_VIEWS, Rig
from service import crud, examples
from service.api.deps import (
    CONFLICT,
    CurrentLab,
    Cursor,
    Limit,
    MetadataQuery,
    NameQuery,
    PathId,
    SessionDep,
    StorageDep,
)
from service.errors import InvalidError
from service.models import RigRow
from service.schemas import RigPage, RigPublic, json_depth, labels_from_query
from service.upload import document_body, read_document, read_documents

router = APIRouter(prefix="/rigs", tags=["rigs"])

DOCUMENT_LIMIT = 1024**2
# A rig nests 5 levels (views, a view, its projection, matrix rows, numbers); keys beside them are
# kept as uploaded and written back in archives, whose JSON encoder recurses per level.
MAX_DEPTH = 32


def _public(row: RigRow) -> RigPublic:
    rig = Rig.from_dict(row.spec)
    return RigPublic(id=row.id, name=row.name, metadata=row.meta, views=[v.name for v in rig.views],
                     videos=rig.n_videos, created_at=row.created_at)


@router.post("", status_code=201, response_model=RigPublic,
             summary="Upload a rig.json (raw JSON body or multipart field 'file')",
             openapi_extra=document_body("application/json", {"type": "object"}, examples.RIG))
async def create_rig(request: Request, session: SessionDep, lab: CurrentLab, name: NameQuery = None,
                     metadata: MetadataQuery = None) -> RigPublic:
    """Store a camera rig (FORMATS §2) sent as the raw JSON body (or a multipart field ``file``);
    ``?name=`` and ``?metadata=`` (a JSON object) label it. Example:
    ``curl -H "$H" -H 'Content-Type: application/json' --data-binary @rig.json "$API/rigs?name=mirrors"``"""
    checked_name, meta = labels_from_query(name, metadata)
    raw = await read_document(request, DOCUMENT_LIMIT)
    try:
        spec = json.loads(raw, parse_constant=_no_constants)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InvalidError(f"rig is not valid JSON: {exc}") from None
    except RecursionError:  # json's decoder recurses per level: 50,000 '[' would be a 500
        raise InvalidError("rig JSON is nested too deeply (a rig file nests a few levels)") from None
    if (depth := json_depth(spec)) > MAX_DEPTH:
        raise InvalidError(f"rig JSON nests {depth} levels deep; a rig nests at most {MAX_DEPTH}")
    row = await run_in_threadpool(crud.create_rig, session, lab, spec, name=checked_name, meta=meta)
    return _public(row)


@router.post(
    "/import", status_code=201, response_model=RigPublic,
    summary="Import another tool's calibration as a rig (multipart field(s) 'file')",
    description=(
        "Converts an Anipose/aniposelib `calibration.toml` (`format=anipose`), OpenCV FileStorage "
        "YAML/XML files (`format=opencv`, one field `file` per camera file) or DLTdv/Argus DLT "
        "coefficients CSV (`format=dlt`, with each camera's image `height`) into a rig (FORMATS §2) "
        "and stores it. Conventions: docs/INTERCHANGE.md. Example: "
        "`curl -F file=@calibration.toml '$API/rigs/import?format=anipose&video_index=0&video_index=1'`"
    ),
)
async def import_calibration(
    request: Request, session: SessionDep, lab: CurrentLab,
    fmt: Annotated[Literal["anipose", "opencv", "dlt"], Query(alias="format", description="the file format")],
    height: Annotated[list[float] | None, Query(
        description="dlt: image height in pixels per camera, or one for all")] = None,
    video_index: Annotated[list[int] | None, Query(
        description="video index of each view in order (default 0, 1, 2, …)")] = None,
    name: NameQuery = None, metadata: MetadataQuery = None,
) -> RigPublic:
    checked_name, meta = labels_from_query(name, metadata)
    documents = await read_documents(request, DOCUMENT_LIMIT, MAX_VIEWS)
    rig = await run_in_threadpool(
        import_rig, fmt, [data for _, data in documents], labels=[name for name, _ in documents],
        heights=height, videos=video_index,
    )
    row = await run_in_threadpool(crud.create_rig, session, lab, rig.to_dict(), name=checked_name, meta=meta)
    return _public(row)


@router.get("", response_model=RigPage, summary="The lab's rigs, newest first")
def list_rigs(session: SessionDep, lab: CurrentLab, cursor: Cursor = None, limit: Limit = 50) -> RigPage:
    """The lab's rigs, newest first, ``limit`` per page; pass ``next_cursor`` as ``?cursor=`` for
    the next page. Example: ``GET /v1/rigs?limit=50``"""
    rows, next_cursor = crud.list_owned(session, RigRow, lab, cursor=cursor, limit=limit)
    return RigPage(items=[_public(row) for row in rows], next_cursor=next_cursor)


@router.get("/{rig_id}", response_model=RigPublic)
def get_rig(rig_id: PathId, session: SessionDep, lab: CurrentLab) -> RigPublic:
    """One rig of the lab: its views, how many videos it takes, name and metadata. Example:
    ``GET /v1/rigs/1``"""
    return _public(crud.owned(session, RigRow, rig_id, lab))


@router.delete("/{rig_id}", status_code=204, response_class=Response, responses=CONFLICT)
def delete_rig(rig_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> Response:
    """Delete the rig (204). 409, naming the jobs, while any job, finished or not, names it (a
    finished job's archive carries its rig.json). Example: ``curl -X DELETE -H "$H" $API/rigs/1``"""
    crud.delete_upload(session, storage, lab, RigRow, rig_id)
    return Response(status_code=204)


def _no_constants(name: str) -> float:
    raise InvalidError(f"rig JSON contains {name}, which is not a number")
