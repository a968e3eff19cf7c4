"""Request bodies read as they stream in: uploads go to storage chunk by chunk, never whole
in memory, and a body over the size limit is refused (413) as soon as it passes the limit."""

from __future__ import annotations

import hashlib
import io
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, BinaryIO

from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.requests import Request

from service.errors import InvalidError
from service.storage import Storage

MULTIPART_SLACK = 64 * 1024  # part headers and boundaries on top of the file itself


class TooLargeError(Exception):
    """The body passed the configured limit (413)."""


@dataclass
class Received:
    """A file stored under ``key``: its name as the client gave it (shown, never used as a path)."""

    key: str
    filename: str
    size: int
    sha256: str


@dataclass
class _FilePart:
    """python-multipart callbacks that write the part named ``file`` to an open file."""

    out: BinaryIO
    limit: int
    digest: hashlib._Hash = field(default_factory=hashlib.sha256)
    size: int = 0
    filename: str | None = None
    _header: bytes = b""
    _value: bytes = b""
    _disposition: bytes = b""
    _writing: bool = False
    _done: bool = False

    def callbacks(self) -> dict[str, Callable[..., None]]:
        return {"on_header_field": self._on_field, "on_header_value": self._on_value,
                "on_header_end": self._on_header_end, "on_headers_finished": self._on_headers,
                "on_part_data": self._on_data, "on_part_end": self._on_part_end}

    def _on_field(self, data: bytes, start: int, end: int) -> None:
        self._header += data[start:end]

    def _on_value(self, data: bytes, start: int, end: int) -> None:
        self._value += data[start:end]

    def _on_header_end(self) -> None:
        if self._header.lower() == b"content-disposition":
            self._disposition = self._value
        self._header = self._value = b""

    def _on_headers(self) -> None:
        _, params = parse_options_header(self._disposition)
        self._disposition = b""
        self._writing = not self._done and params.get(b"name") == b"file"
        if self._writing:
            self.filename = display_name(params.get(b"filename", b"upload").decode("utf-8", "replace"))

    def _on_data(self, data: bytes, start: int, end: int) -> None:
        if not self._writing:
            return
        self.size += end - start
        if self.size > self.limit:
            raise TooLargeError
        self.digest.update(data[start:end])
        self.out.write(data[start:end])

    def _on_part_end(self) -> None:
        self._done = self._done or self._writing
        self._writing = False


async def receive_video(request: Request, storage: Storage, limit: int) -> Received:
    """Stream the multipart field ``file`` into storage under a fresh key (atomic: all or nothing)."""
    boundary = _boundary(request, "upload the video as multipart/form-data (with a boundary) and a "
                                  "field named 'file'")
    check_length(request, limit + MULTIPART_SLACK)
    key = f"videos/{uuid.uuid4().hex}"
    with storage.writer(key) as out:
        part = await _stream_file_part(request, boundary, out, limit)
    return Received(key, part.filename or "upload", part.size, part.digest.hexdigest())


async def read_document(request: Request, limit: int) -> bytes:
    """A small document (model XML, rig JSON): the raw body, or a multipart field ``file``;
    either is refused (413) as soon as it passes ``limit`` bytes, never read whole first."""
    check_length(request, limit + MULTIPART_SLACK)
    content_type, _ = parse_options_header(request.headers.get("content-type", ""))
    if content_type == b"multipart/form-data":
        out = io.BytesIO()
        await _stream_file_part(request, _boundary(request, ""), out, limit)
        data = out.getvalue()
    else:
        chunks, size = [], 0
        async for chunk in request.stream():
            size += len(chunk)
            if size > limit:
                raise TooLargeError
            chunks.append(chunk)
        data = b"".join(chunks)
    if not data.strip():
        raise InvalidError("the request body is empty")
    return data


def _boundary(request: Request, problem: str) -> bytes:
    """The multipart boundary of the request's Content-Type; ``problem`` (422) without one."""
    content_type, params = parse_options_header(request.headers.get("content-type", ""))
    if content_type != b"multipart/form-data" or not params.get(b"boundary"):
        raise InvalidError(problem or "a multipart/form-data body needs a boundary in its Content-Type")
    return params[b"boundary"]


async def _stream_file_part(request: Request, boundary: bytes, out: BinaryIO, limit: int) -> _FilePart:
    """Parse the multipart body as it arrives, writing the field ``file`` to ``out``: 413 as soon
    as the file passes ``limit`` bytes (or the body ``limit`` plus the multipart overhead), 422
    for a malformed body or one without that field."""
    part = _FilePart(out, limit)
    parser = MultipartParser(boundary, part.callbacks())  # type: ignore[arg-type]
    received = 0
    try:
        async for chunk in request.stream():
            received += len(chunk)
            if received > limit + MULTIPART_SLACK:
                raise TooLargeError
            parser.write(chunk)
        parser.finalize()
    except FormParserError as exc:
        raise InvalidError(f"the multipart body is malformed: {exc}") from None
    if part.filename is None:
        raise InvalidError("the multipart body has no file field named 'file'")
    return part


async def read_documents(request: Request, limit: int, max_files: int) -> list[tuple[str, bytes]]:
    """Small documents sent as multipart fields ``file`` (several may share the name), as
    (display name, content); ``limit`` bounds the whole body."""
    check_length(request, limit + MULTIPART_SLACK)
    content_type, _ = parse_options_header(request.headers.get("content-type", ""))
    if content_type != b"multipart/form-data":
        raise InvalidError("send the calibration file(s) as multipart/form-data fields named 'file'")
    buffered = await _buffered(request, limit + MULTIPART_SLACK)
    form = await buffered.form(max_files=max_files, max_fields=max_files + 10, max_part_size=limit)
    documents, total = [], 0
    for upload in form.getlist("file"):
        if isinstance(upload, str):
            raise InvalidError("the multipart field 'file' must be a file, not a text field")
        data = await upload.read(limit + 1)
        total += len(data)
        if total > limit:
            raise TooLargeError
        documents.append((display_name(upload.filename or "upload"), data))
    if not documents:
        raise InvalidError("the multipart body has no file field named 'file'")
    return documents


async def _body(request: Request, limit: int) -> bytes:
    """The whole body, refused (413) as soon as it passes ``limit``, declared length or not."""
    data = bytearray()
    async for chunk in request.stream():
        data += chunk
        if len(data) > limit:
            raise TooLargeError
    return bytes(data)


async def _buffered(request: Request, limit: int) -> Request:
    """The request with its body read first, within ``limit``. Starlette's form parser bounds
    text fields (``max_part_size``) but spools file fields to disk without limit, so a chunked
    body (no Content-Length for :func:`check_length`) could otherwise fill the disk."""
    body = await _body(request, limit)

    async def receive() -> dict[str, object]:
        return {"type": "http.request", "body": body, "more_body": False}

    return Request(request.scope, receive)


def document_body(media_type: str, schema: dict[str, Any], example: Any) -> dict[str, Any]:
    """``openapi_extra`` describing a body these routes read themselves (:func:`read_document`):
    ``media_type`` with ``example``, or the same file as a multipart field ``file``."""
    return {"requestBody": {"required": True, "content": {
        media_type: {"schema": schema, "example": example}, **FILE_BODY["requestBody"]["content"]}}}


# ``openapi_extra`` of a body sent as the multipart field ``file`` (:func:`receive_video`).
FILE_BODY: dict[str, Any] = {"requestBody": {"required": True, "content": {"multipart/form-data": {
    "schema": {"type": "object", "properties": {"file": {"type": "string", "format": "binary"}},
               "required": ["file"]}}}}}


def display_name(filename: str) -> str:
    """The client's filename as shown back: its last path component, without control characters
    (PostgreSQL text cannot hold NUL), at most 255 characters. Never used as a path."""
    name = filename.replace("\\", "/").rsplit("/", 1)[-1]
    name = "".join(c for c in name if c.isprintable()).strip()
    return (name if name not in ("", ".", "..") else "upload")[:255]


def declared_length(request: Request) -> int:
    """The body's Content-Length, 0 when absent or not a number (chunked uploads)."""
    length = request.headers.get("content-length", "")
    return int(length) if length.isdigit() else 0


def check_length(request: Request, limit: int) -> None:
    """413 at once for a body that declares more than ``limit`` bytes."""
    if declared_length(request) > limit:
        raise TooLargeError
