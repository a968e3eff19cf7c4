"""Request bodies: taken only from a known lab, only up to the route's limit, only while they keep coming.

An ASGI middleware in front of every route, for requests that carry a body
(``Content-Length`` > 0, or chunked):

- Under ``/v1`` the key is checked first, before a byte of the body is read: 401 (429 for an
  address over the failure limit) at once. FastAPI reads a JSON body before it resolves the route's
  dependencies, so the route's own check alone would come after a 100 MB body was read.
- A body declaring more than its route accepts (:func:`body_limit`) is 413 before it is
  read; a chunked one is 413 as soon as it passes the limit.
- A body must keep coming (uvicorn has no timeout on it): 408 when no byte arrives for
  ``body_timeout_s``, or when the time spent waiting for it passes ``body_timeout_s`` plus
  the time its bytes so far take at ``body_min_bytes_per_s`` (a slow-loris sending a byte a
  second). Time the route spends not reading does not count.
- A response sent before the whole body was read carries ``Connection: close``, so uvicorn
  closes the connection instead of reading and discarding the rest.

The routes keep their own exact checks (a video's limit counts the file, not the multipart
body around it); this layer bounds what reaches them.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from fastapi import HTTPException
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.auth import authenticate, bearer_token
from service.api.routes import models, rigs
from service.db import read_session_factory
from service.models import Lab
from service.settings import Settings, get_settings
from service.upload import MULTIPART_SLACK

# Bodies of the JSON routes (jobs, batches) and of any route not listed in body_limit. The
# largest valid one, a batch of 1000 trials of 16 ten-digit video ids, is ~190 KB.
JSON_BODY_LIMIT = 256 * 1024
CLOSE = {"Connection": "close"}


def body_limit(path: str, settings: Settings) -> int:
    """Bytes a request body to ``path`` may have, multipart overhead included."""
    documents = {"/v1/videos": settings.max_upload_bytes, "/v1/models": models.DOCUMENT_LIMIT,
                 "/v1/rigs": rigs.DOCUMENT_LIMIT, "/v1/rigs/import": rigs.DOCUMENT_LIMIT}
    limit = documents.get(path.rstrip("/"))
    return JSON_BODY_LIMIT if limit is None else limit + MULTIPART_SLACK


class RequestGuard:
    """The middleware (see the module docstring)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = Headers(scope=scope) if scope["type"] == "http" else Headers()
        declared = _declared_length(headers)
        if declared in (None, 0) and "transfer-encoding" not in headers:  # no body (or not HTTP)
            await self.app(scope, receive, send)
            return
        settings = get_settings()
        limit = body_limit(scope["path"], settings)
        if scope["path"].startswith("/v1/"):
            client = scope.get("client")
            try:
                await run_in_threadpool(_authenticate, headers.get("authorization"),
                                        client[0] if client else None)
            except HTTPException as exc:
                await _refuse(scope, receive, send, exc.status_code, str(exc.detail), exc.headers)
                return
        if declared is not None and declared > limit:
            await _refuse(scope, receive, send, 413, f"the request body ({declared} bytes) is larger "
                          f"than this server accepts for {scope['path']} ({limit} bytes at most)")
            return
        body = _Body(receive, limit, settings, scope["path"])
        await self.app(scope, body.receive, body.sender(send))


class _Body:
    """``receive`` with the size limit and the clocks; ``sender`` closes an unread body's connection."""

    def __init__(self, receive: Receive, limit: int, settings: Settings, path: str) -> None:
        self._receive, self.limit, self.path = receive, limit, path
        self.idle_s, self.min_rate = settings.body_timeout_s, settings.body_min_bytes_per_s
        # Only time spent waiting for the client counts: a route that reads late (a lock, a
        # database lookup) must not make a fast client's body time out.
        self.waited, self.received, self.done = 0.0, 0, False

    async def receive(self) -> Message:
        if self.done:
            return await self._receive()
        # Waiting so far may total idle_s plus the time `received` bytes take at the minimum rate.
        allowed = self.idle_s + self.received / self.min_rate - self.waited
        start = time.monotonic()
        try:
            message = await asyncio.wait_for(self._receive(), max(0.0, min(self.idle_s, allowed)))
        except TimeoutError:
            raise HTTPException(408, f"the request body came too slowly ({self.received} bytes in "
                                f"{self.waited + time.monotonic() - start:.0f} s); send at least "
                                f"{self.min_rate} bytes/s, and a byte at least every {self.idle_s:g} s",
                                CLOSE) from None
        self.waited += time.monotonic() - start
        if message["type"] != "http.request" or not message.get("more_body", False):
            self.done = True
        self.received += len(message.get("body", b""))
        if self.received > self.limit:
            raise HTTPException(413, f"the request body is larger than this server accepts for "
                                f"{self.path} ({self.limit} bytes at most)", CLOSE)
        return message

    def sender(self, send: Send) -> Send:
        async def guarded(message: Message) -> None:
            if message["type"] == "http.response.start" and not self.done:
                message = {**message, "headers": [*message.get("headers", []), (b"connection", b"close")]}
            await send(message)

        return guarded


def _authenticate(authorization: str | None, address: str | None) -> Lab:
    with read_session_factory()() as session:
        return authenticate(session, bearer_token(authorization), address)


async def _refuse(scope: Scope, receive: Receive, send: Send, status: int, detail: str,
                  headers: Any = None) -> None:
    """Answer without reading the body, and close the connection (the body is never read)."""
    response = JSONResponse({"detail": detail}, status_code=status, headers={**(headers or {}), **CLOSE})
    await response(scope, receive, send)


def _declared_length(headers: Headers) -> int | None:
    """Content-Length, None when absent or not a number."""
    length = headers.get("content-length", "")
    return int(length) if length.isdigit() else None
