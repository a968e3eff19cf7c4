"""Kinematic models (FORMATS §1) and their histogram archives (FORMATS §4)."""

from __future__ import annotations

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from core.model import KinematicModel
from service import crud, examples, histstore
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
from service.models import Model
from service.schemas import (
    MAX_DB_INT,
    ExistingArchive,
    ModelCreated,
    ModelPage,
    ModelPublic,
    labels_from_query,
)
from service.upload import document_body, read_document

router = APIRouter(prefix="/models", tags=["models"])

DOCUMENT_LIMIT = 10 * 1024**2
REUSE = ("true: if this lab has an identical model (same XML bytes), answer 200 with that model "
         "instead of storing a new one with a fresh archive")
XML = "application/xml"


def _public(session: SessionDep, row: Model, kinematic: KinematicModel | None = None) -> ModelPublic:
    """``row`` as answered; ``kinematic`` is its XML parsed, where the caller has it already."""
    kinematic = kinematic or KinematicModel.from_xml(row.xml)
    return ModelPublic(id=row.id, name=row.name, dofs=kinematic.dof_names,
                       histogram_versions=crud.histogram_versions(session, row), sha256=row.sha256,
                       metadata=row.meta, created_at=row.created_at)


def _created(session: SessionDep, row: Model, existing: Model | None) -> ModelCreated:
    archive = None if existing is None else ExistingArchive(
        model_id=existing.id, histogram_versions=crud.histogram_versions(session, existing),
        latest_version=crud.histogram_version(session, existing, None).version)
    kinematic = KinematicModel.from_xml(row.xml)
    advice = kinematic.identifiability.advice()
    return ModelCreated(**_public(session, row, kinematic).model_dump(),
                        existing_model_id=None if existing is None else existing.id,
                        existing=archive, reused=row is existing, warnings=[advice] if advice else [])


@router.post("", status_code=201, response_model=ModelCreated,
             summary="Upload a model.xml (raw body or multipart field 'file')",
             responses={200: {"model": ModelCreated, "description": "?reuse=true: the identical model"}},
             openapi_extra=document_body("application/xml", {"type": "string"}, examples.MODEL_XML))
async def create_model(request: Request, response: Response, session: SessionDep, storage: StorageDep,
                       lab: CurrentLab, name: NameQuery = None, metadata: MetadataQuery = None,
                       reuse: bool = Query(default=False, description=REUSE)) -> ModelCreated:
    """Store a kinematic model (FORMATS §1) sent as the raw XML body (or a multipart field
    ``file``); its histogram archive starts at version 1 (uniform). ``?name=`` and ``?metadata=``
    (a JSON object) label it. If this lab already has a model with the same XML bytes, the answer
    names it in ``existing_model_id`` and ``existing`` (its archive's versions): submit jobs with
    that id to go on with its archive; ``?reuse=true`` answers 200 with that model instead of
    storing a new one. Another lab's identical model is never named. ``warnings`` says what
    is wrong with a model that can still be fitted (DOFs its markers cannot determine).

    Example: ``curl -H "$H" --data-binary @model.xml "$API/models?name=locust&reuse=true"``"""
    checked_name, meta = labels_from_query(name, metadata)
    xml = await read_document(request, DOCUMENT_LIMIT)
    row, existing = await run_in_threadpool(crud.store_model, session, storage, lab, xml,
                                            name=checked_name, meta=meta, reuse=reuse)
    if row is existing:
        response.status_code = 200
    return await run_in_threadpool(_created, session, row, existing)


@router.get("", response_model=ModelPage, summary="The lab's models, newest first")
def list_models(session: SessionDep, lab: CurrentLab, cursor: Cursor = None, limit: Limit = 50) -> ModelPage:
    """The lab's models, newest first, ``limit`` per page; pass ``next_cursor`` as ``?cursor=``
    for the next page. Example: ``GET /v1/models?limit=50``"""
    rows, next_cursor = crud.list_owned(session, Model, lab, cursor=cursor, limit=limit)
    return ModelPage(items=[_public(session, row) for row in rows], next_cursor=next_cursor)


@router.get("/{model_id}", response_model=ModelPublic)
def get_model(model_id: PathId, session: SessionDep, lab: CurrentLab) -> ModelPublic:
    """One model of the lab: its name, DOFs, histogram archive versions, content hash and
    metadata (404 for another lab's). Example: ``GET /v1/models/1``"""
    return _public(session, crud.owned(session, Model, model_id, lab))


@router.delete("/{model_id}", status_code=204, response_class=Response, responses=CONFLICT)
def delete_model(model_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> Response:
    """Delete the model and its histogram archive (204). 409, naming the jobs, while any job,
    finished or not, names it (a finished job's archive carries its model.xml). Example:
    ``curl -X DELETE -H "$H" $API/models/1``"""
    crud.delete_upload(session, storage, lab, Model, model_id)
    return Response(status_code=204)


@router.get("/{model_id}/model.xml", response_class=Response, responses={200: {"content": {XML: {}}}})
def get_model_xml(model_id: PathId, session: SessionDep, lab: CurrentLab) -> Response:
    """The model's XML as uploaded. Example: ``GET /v1/models/1/model.xml``"""
    return Response(crud.owned(session, Model, model_id, lab).xml, media_type=XML)


@router.get("/{model_id}/histograms.xml", response_class=Response, responses={200: {"content": {XML: {}}}},
            summary="The model's histogram archive: the latest version, or ?version=N")
def get_histograms(model_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab,
                   version: int | None = Query(default=None, ge=1, le=MAX_DB_INT)) -> Response:
    """The model's histogram archive (FORMATS §4) as XML: the latest version, or ``?version=N``;
    the version is in the ``X-Histogram-Version`` header. Example:
    ``GET /v1/models/1/histograms.xml?version=2``"""
    row = crud.owned(session, Model, model_id, lab)
    stored = crud.histogram_version(session, row, version)
    histograms = histstore.load(storage, stored.storage_key, KinematicModel.from_xml(row.xml))
    return Response(histograms.to_xml(), media_type=XML,
                    headers={"X-Histogram-Version": str(stored.version)})
