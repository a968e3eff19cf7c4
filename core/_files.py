"""Reading user documents (model XML, rig JSON, histogram XML) with a bound on their size."""

from __future__ import annotations

from pathlib import Path


def read_bounded(source: str | bytes | Path, limit: int, what: str, error: type[ValueError]) -> str | bytes:
    """The document: text or bytes as given, or a file's bytes read no further than ``limit`` + 1.

    A huge file then costs nothing, and only a regular file is opened: a FIFO or a device
    would block or never end. Raises ``error`` naming ``what`` when the file cannot be read
    or the document is longer than ``limit``.
    """
    if isinstance(source, Path):
        try:
            if not source.is_file():
                raise OSError(f"{source} is not a regular file")
            with source.open("rb") as f:
                source = f.read(limit + 1)
        except OSError as exc:
            raise error(f"cannot read {what}: {exc}") from exc
    if len(source) > limit:
        raise error(f"{what} is larger than {limit} bytes")
    return source
