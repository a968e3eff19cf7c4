"""Dependencies of every route: a database session, the caller's lab, the storage, settings."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated, Any

from fastapi import Depends, Path, Query, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from service.api.auth import authenticate
from service.db import read_session_factory, session_factory
from service.models import Lab
from service.schemas import MAX_DB_INT, Problem
from service.settings import Settings, get_settings
from service.storage import LocalStorage, get_storage


def get_session(request: Request) -> Iterator[Session]:
    """A session per request; GET requests only read, so they never wait for a writer (SQLite)."""
    factory = read_session_factory() if request.method in ("GET", "HEAD") else session_factory()
    with factory() as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session)]
# A resource id in a URL: within the 32-bit id columns (larger ones are 422, never a failed query).
PathId = Annotated[int, Path(ge=1, le=MAX_DB_INT)]
# A listing's page: after ``cursor`` (the ``next_cursor`` of the page before), ``limit`` rows at most.
Cursor = Annotated[int | None, Query(ge=1, le=MAX_DB_INT, description="next_cursor of the last page")]
Limit = Annotated[int, Query(ge=1, le=200)]
# An upload's name and metadata: query parameters, the body being the file itself.
NameQuery = Annotated[str | None, Query(description="the lab's name for the upload (1-200 characters)",
                                        examples=["walk-07"])]
MetadataQuery = Annotated[str | None, Query(
    description="free metadata: a JSON object (bounds: see the schemas' metadata)",
    examples=['{"subject": "locust 7", "condition": "walking"}'])]
# Errors every /v1 operation may answer, all {"detail": "..."} (service/api/app.py).
ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": Problem, "description": "no valid API key"},
    404: {"model": Problem, "description": "no such id in this lab (another lab's ids look the same)"},
    422: {"model": Problem, "description": "invalid input; the message names the field, id or file"},
}
# The 409 of deleting an upload a job uses.
CONFLICT: dict[int | str, dict[str, Any]] = {
    409: {"model": Problem, "description": "a job uses it; the message names the jobs"}}
StorageDep = Annotated[LocalStorage, Depends(get_storage)]
SettingsDep = Annotated[Settings, Depends(get_settings)]

_bearer = HTTPBearer(auto_error=False, description="the lab's API key (`mocap admin create-lab`)")


def current_lab(
    request: Request, session: SessionDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Lab:
    """The lab whose key the request carries; 401 without a valid one (``service.api.auth``)."""
    token = credentials.credentials if credentials is not None else None
    return authenticate(session, token, request.client.host if request.client else None)


CurrentLab = Annotated[Lab, Depends(current_lab)]
