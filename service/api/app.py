"""The FastAPI application: routers under ``/v1`` and errors as ``{"detail": "..."}``.

Invalid models, rigs, histograms and videos (``core``'s ModelError, RigError,
HistogramError, VideoError, and ValueError from option checks) are 422 with
core's message, which names the element or option at fault.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import SQLAlchemyError

from service import crud
from service.api.deps import ERRORS
from service.api.guard import RequestGuard
from service.api.routes import apidocs, batches, dashboard, jobs, models, rigs, videos
from service.db import read_session_factory
from service.errors import ConflictError, NotFoundError, QueueUnavailableError, RateLimitedError
from service.storage import get_storage
from service.upload import TooLargeError

logger = logging.getLogger(__name__)


# A stored video or histogram file this old without a row is an orphan; a younger one may be
# being probed or registered.
ORPHAN_AGE_S = 3600


@asynccontextmanager
async def _lifespan(_app: FastAPI) -> AsyncIterator[None]:
    """On start, delete the partial uploads of an API process that died mid-upload, the
    complete ones it stored but never registered, and the files of deleted uploads whose
    deletion a crash interrupted."""
    storage = get_storage()
    storage.remove_abandoned()
    try:
        with read_session_factory()() as session:
            crud.remove_orphans(session, storage, ORPHAN_AGE_S)
    except SQLAlchemyError:  # the database is down: serve anyway (requests will say so), sweep next start
        logger.exception("orphan files not swept: the database cannot be read")
    yield


def create_app() -> FastAPI:
    app = FastAPI(title="mocap", version="1", lifespan=_lifespan, docs_url=None, redoc_url=None,
                  description="Model-based motion capture as a service: upload models, rigs and "
                              "videos, submit fitting jobs, download angles and histograms.")
    for router in (models.router, rigs.router, videos.router, jobs.router, batches.router):
        app.include_router(router, prefix="/v1", responses=ERRORS)
    # The lab dashboard at / and the API docs at /docs, /redoc, with every asset served from here.
    app.include_router(dashboard.router)
    app.include_router(apidocs.router)
    app.mount(dashboard.STATIC_URL, StaticFiles(directory=dashboard.STATIC_DIR), name="dashboard-static")
    app.mount(apidocs.ASSETS_URL, StaticFiles(directory=apidocs.ASSETS_DIR), name="apidocs-static")
    app.add_middleware(RequestGuard)  # key, size and pace of a body checked before it is read
    _errors(app)
    return app


def _errors(app: FastAPI) -> None:
    def handler(status: int):  # type: ignore[no-untyped-def]
        async def respond(_request: Request, exc: Exception) -> JSONResponse:
            return JSONResponse({"detail": str(exc) or default[status]}, status_code=status)
        return respond

    default = {404: "not found", 409: "conflict", 422: "invalid input", 503: "unavailable"}
    app.add_exception_handler(NotFoundError, handler(404))
    app.add_exception_handler(ConflictError, handler(409))
    app.add_exception_handler(QueueUnavailableError, handler(503))
    app.add_exception_handler(ValueError, handler(422))  # core's ModelError, RigError, VideoError…

    async def too_large(_request: Request, _exc: Exception) -> JSONResponse:
        return JSONResponse({"detail": "the upload is larger than this server accepts"}, status_code=413)

    async def invalid_request(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc'] if p != 'body') or 'body'}: {e['msg']}"
            for e in exc.errors()
        )
        return JSONResponse({"detail": problems}, status_code=422)

    async def rate_limited(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RateLimitedError)
        return JSONResponse({"detail": str(exc)}, status_code=429,
                            headers={"Retry-After": str(exc.retry_after)})

    app.add_exception_handler(TooLargeError, too_large)
    app.add_exception_handler(RateLimitedError, rate_limited)
    app.add_exception_handler(RequestValidationError, invalid_request)
