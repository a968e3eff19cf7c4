"""Storage of uploads and results behind one small interface, shared by API and workers.

Keys are built by the service (``videos/<uuid>.avi``, ``jobs/<id>/angles.csv``),
never from a user's filename. Writes are atomic: data goes to a temporary file
in the same directory and is renamed into place once complete, so a reader (or
a database row) never sees a partial file, even if the writer dies midway.

A writer killed midway (SIGKILL, power loss) leaves its ``.partial-*`` file behind.
Each writer holds an exclusive ``flock`` on its temporary file while writing, and the
kernel drops the lock when the process dies: :meth:`LocalStorage.remove_abandoned`
(run when the API starts) deletes exactly the partial files nobody holds, so it never
pulls a file from under a live writer in another API or worker process.
"""

from __future__ import annotations

import fcntl
import logging
import os
import re
import tempfile
import time
from collections.abc import Iterable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import BinaryIO, Protocol

from service.settings import get_settings

logger = logging.getLogger(__name__)
PARTIAL_PREFIX = ".partial-"
_KEY = re.compile(r"^[A-Za-z0-9_-]+(/[A-Za-z0-9_.-]+)*$")


class Storage(Protocol):
    """What the service needs of a blob store."""

    def put(self, key: str, chunks: Iterable[bytes]) -> int: ...
    def writer(self, key: str) -> AbstractContextManager[BinaryIO]: ...
    def open(self, key: str) -> BinaryIO: ...
    def path(self, key: str) -> Path: ...
    def exists(self, key: str) -> bool: ...
    def delete(self, key: str) -> None: ...


class LocalStorage:
    """A directory on a disk shared by the API and the workers (a volume in docker-compose)."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> Path:
        """The file of ``key``; keys with ``..``, absolute paths or odd characters are refused."""
        if not _KEY.match(key) or ".." in key.split("/"):
            raise ValueError(f"invalid storage key {key!r}")
        return self.root / key

    @contextmanager
    def writer(self, key: str) -> Iterator[BinaryIO]:
        """A file to write ``key`` into; it appears under ``key`` only if the block succeeds."""
        final = self.path(key)
        final.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=final.parent, prefix=PARTIAL_PREFIX)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # "a live writer", for remove_abandoned; freed on close
            with os.fdopen(fd, "wb") as f:
                yield f
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, final)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def put(self, key: str, chunks: Iterable[bytes]) -> int:
        """Store ``chunks`` under ``key`` atomically; return the number of bytes."""
        size = 0
        with self.writer(key) as f:
            for chunk in chunks:
                f.write(chunk)
                size += len(chunk)
        return size

    def open(self, key: str) -> BinaryIO:
        return open(self.path(key), "rb")

    def exists(self, key: str) -> bool:
        return self.path(key).is_file()

    def remove_abandoned(self) -> int:
        """Delete partial files no live writer holds (their writer died); return how many."""
        removed = 0
        for path in self.root.rglob(PARTIAL_PREFIX + "*"):
            try:
                with open(path, "rb") as f:
                    fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                    path.unlink()
                    removed += 1
            except (BlockingIOError, FileNotFoundError):
                continue  # being written, or already gone
        if removed:
            logger.warning("removed %d partial file(s) left by writers that died", removed)
        return removed

    def delete(self, key: str) -> None:
        self.path(key).unlink(missing_ok=True)

    def folders(self, parent: str) -> list[str]:
        """Keys of the folders directly in ``parent`` (none if it does not exist)."""
        base = self.path(parent)
        return sorted(f"{parent}/{p.name}" for p in base.iterdir() if p.is_dir()) if base.is_dir() else []

    def files(self, folder: str, older_than_s: float = 0.0) -> Iterator[tuple[str, int]]:
        """(key, size in bytes) of the complete files in ``folder`` last written more than
        ``older_than_s`` seconds ago (partial files are :meth:`remove_abandoned`'s)."""
        cutoff = time.time() - older_than_s
        for path in sorted(self.path(folder).glob("*")):
            try:
                stat = path.stat()
            except FileNotFoundError:  # deleted meanwhile
                continue
            if path.is_file() and not path.name.startswith(PARTIAL_PREFIX) and stat.st_mtime < cutoff:
                yield f"{folder}/{path.name}", stat.st_size


def get_storage() -> LocalStorage:
    """The storage of this process's settings."""
    return LocalStorage(get_settings().storage_dir)
