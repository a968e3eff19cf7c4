"""Kinematic models (FORMATS §1) and their histogram archives (FORMATS §4)."""

from __future__ import annotations

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from core.model import KinematicModel
from service import crud, histstore
from service.api.deps import CurrentLab, Cursor, Limit, PathId, SessionDep, StorageDep
from service.models import Model
from service.schemas import MAX_DB_INT, ModelPage, ModelPublic
from service.upload import read_document

router = APIRouter(prefix="/models", tags=["models"])

DOCUMENT_LIMIT = 10 * 1024**2
XML = "application/xml"


def _public(session: SessionDep, row: Model) -> ModelPublic:
    return ModelPublic(id=row.id, name=row.name, dofs=KinematicModel.from_xml(row.xml).dof_names,
                       histogram_versions=crud.histogram_versions(session, row), created_at=row.created_at)


@router.post("", status_code=201, response_model=ModelPublic,
             summary="Upload a model.xml (raw body or multipart field 'file')")
async def create_model(request: Request, session: SessionDep, storage: StorageDep,
                       lab: CurrentLab) -> ModelPublic:
    xml = await read_document(request, DOCUMENT_LIMIT)
    row = await run_in_threadpool(crud.create_model, session, storage, lab, xml)
    return await run_in_threadpool(_public, session, row)


@router.get("", response_model=ModelPage, summary="The lab's models, newest first")
def list_models(session: SessionDep, lab: CurrentLab, cursor: Cursor = None, limit: Limit = 50) -> ModelPage:
    rows, next_cursor = crud.list_owned(session, Model, lab, cursor=cursor, limit=limit)
    return ModelPage(items=[_public(session, row) for row in rows], next_cursor=next_cursor)


@router.get("/{model_id}", response_model=ModelPublic)
def get_model(model_id: PathId, session: SessionDep, lab: CurrentLab) -> ModelPublic:
    return _public(session, crud.owned(session, Model, model_id, lab))


@router.get("/{model_id}/model.xml", response_class=Response)
def get_model_xml(model_id: PathId, session: SessionDep, lab: CurrentLab) -> Response:
    return Response(crud.owned(session, Model, model_id, lab).xml, media_type=XML)


@router.get("/{model_id}/histograms.xml", response_class=Response,
            summary="The model's histogram archive: the latest version, or ?version=N")
def get_histograms(model_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab,
                   version: int | None = Query(default=None, ge=1, le=MAX_DB_INT)) -> Response:
    row = crud.owned(session, Model, model_id, lab)
    stored = crud.histogram_version(session, row, version)
    histograms = histstore.load(storage, stored.storage_key, KinematicModel.from_xml(row.xml))
    return Response(histograms.to_xml(), media_type=XML,
                    headers={"X-Histogram-Version": str(stored.version)})
