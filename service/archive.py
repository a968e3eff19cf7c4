"""Zip archives streamed as they are written: no archive is ever held whole in memory or on disk."""

from __future__ import annotations

import re
import time
import zipfile
from collections.abc import Iterable, Iterator
from typing import BinaryIO

from service.models import Job
from service.storage import Storage

_BLOCK = 1 << 20
FOLDER_NAME_CHARS = 60
_UNSAFE = re.compile(r"[^\w.-]+")  # \w: letters and digits of any script, and "_"


def trial_folder(job: Job) -> str:
    """A batch trial's folder in the batch archive: ``trial-003-job-12/``, with the trial's name
    after it when it has one (``trial-003-job-12-walk_fast/``). Trial index and job id make it
    unique in the archive, even for trials of the same name; the name is sanitised to letters,
    digits, ``._-`` (no path separators), without leading dots (never ``..``)."""
    folder = f"trial-{job.trial:03d}-job-{job.id}"
    name = _UNSAFE.sub("_", job.name or "").lstrip(".")[:FOLDER_NAME_CHARS]
    return f"{folder}-{name}/" if name else f"{folder}/"


class _Sink:
    """A write-only file whose written bytes are taken out by :meth:`drain` (zipfile streams to it)."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []

    def write(self, data: bytes) -> int:
        self._parts.append(bytes(data))
        return len(data)

    def flush(self) -> None:
        """Nothing buffered here beyond the parts :meth:`drain` hands out."""

    def drain(self) -> bytes:
        data, self._parts = b"".join(self._parts), []
        return data


def stream_zip(entries: Iterable[tuple[str, Storage, str] | tuple[str, bytes]]) -> Iterator[bytes]:
    """Yield a zip of ``entries``: (name, storage, key) copies a stored file, (name, bytes) a small one."""
    sink = _Sink()
    with zipfile.ZipFile(sink, "w", compression=zipfile.ZIP_DEFLATED) as archive:  # type: ignore[call-overload]
        for entry in entries:
            info = zipfile.ZipInfo(entry[0], date_time=time.localtime()[:6])
            info.compress_type = zipfile.ZIP_DEFLATED
            with archive.open(info, "w") as dest:
                if len(entry) == 2:
                    dest.write(entry[1])
                else:
                    with entry[1].open(entry[2]) as src:
                        yield from _copy(src, dest, sink)
            yield sink.drain()
    yield sink.drain()


def _copy(src: BinaryIO, dest: BinaryIO, sink: _Sink) -> Iterator[bytes]:
    while block := src.read(_BLOCK):
        dest.write(block)
        yield sink.drain()
