"""The lab's documents (model XML, rig JSON, histogram XML, CSV tables): reading with a bound
on their size, and the C-locale decimal syntax of their numbers.

Numbers are written without exponents, the shortest digits that read back to the same
float, and read refusing Python's extras ('1_0', non-ASCII digits), so that a typo cannot
silently become another number.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


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


def parse_decimal(raw: str) -> float:
    """``float(raw)`` for C-locale decimals only (raises ValueError otherwise).

    >>> parse_decimal("-4.5e-1")
    -0.45
    """
    if "_" in raw or not raw.isascii():
        raise ValueError(f"could not convert string to float: {raw!r}")
    return float(raw)


def decimal(value: float) -> str:
    """A C-locale decimal (never an exponent), shortest that reads back to the same float;
    negative zero is written 0.

    >>> decimal(4.0), decimal(1e-05), decimal(-0.5), decimal(-0.0), decimal(1e-7)
    ('4', '0.00001', '-0.5', '0', '0.0000001')
    """
    return np.format_float_positional(float(value) + 0.0, trim="-")
