"""The per-image results table ``angles.csv`` (FORMATS §3) and the timing of samples.

Columns: ``sample,frame,field,time_s,<dof names in model order>,error_px,attempts,status``.
DOFs are reported in their own range (no wrapping), C-locale decimals. An image
without detections has empty DOF and error cells: there is no posture to report.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from core.fields import field_parities
from core.fit import ImageFit, Status
from core.model import KinematicModel

__all__ = ["SampleClock", "angles_header", "read_angles_csv", "write_angles_csv"]


@dataclass(frozen=True)
class SampleClock:
    """Maps an analysed image (sample) to its video frame, field and time.

    Without de-interlacing a sample is a frame. De-interlaced, frame k gives
    sample 2k (the field exposed first, at k/fps) and sample 2k+1 (the other
    field, half a frame period later), e.g. PAL: 50 images/s from 25 frames/s.
    ``field_order`` says which rows come first: 'even-first' (rows 0, 2, …) or
    'odd-first' (see ``core.fields``).
    """

    fps: float
    deinterlaced: bool = False
    field_order: str = "even-first"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be a positive number, got {self.fps!r}")
        field_parities(self.field_order)

    def frame(self, sample: int) -> int:
        return sample // 2 if self.deinterlaced else sample

    def field(self, sample: int) -> str:
        if not self.deinterlaced:
            return ""
        return ("even", "odd")[field_parities(self.field_order)[sample % 2]]

    def time(self, sample: int) -> float:
        if not self.deinterlaced:
            return sample / self.fps
        return (sample // 2) / self.fps + (sample % 2) / (2.0 * self.fps)


def angles_header(model: KinematicModel) -> list[str]:
    return ["sample", "frame", "field", "time_s", *model.dof_names, "error_px", "attempts", "status"]


def write_angles_csv(
    out: Path | TextIO, model: KinematicModel, fits: Iterable[ImageFit], clock: SampleClock
) -> None:
    """Write ``angles.csv``: one row per fit, in the order given (sample order)."""
    if isinstance(out, Path):
        with out.open("w", newline="") as fh:
            write_angles_csv(fh, model, fits, clock)
        return
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(angles_header(model))
    for f in fits:
        dofs = ["" if not math.isfinite(v) else f"{v:.6f}" for v in f.dofs]
        error = "" if not math.isfinite(f.error) else f"{f.error:.4f}"
        writer.writerow(
            [f.sample, clock.frame(f.sample), clock.field(f.sample), f"{clock.time(f.sample):.6f}",
             *dofs, error, f.attempts, f.status.value]
        )


@dataclass(frozen=True)
class AnglesTable:
    """angles.csv read back: DOF values (N, D) with NaN for empty cells, and the other columns."""

    dof_names: list[str]
    samples: np.ndarray
    frames: np.ndarray
    fields: list[str]
    times: np.ndarray
    dofs: np.ndarray
    errors: np.ndarray
    attempts: np.ndarray
    statuses: list[Status]


def read_angles_csv(path: Path) -> AnglesTable:
    """Read an ``angles.csv`` written by :func:`write_angles_csv` (or any FORMATS §3 file)."""
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty file, expected an angles.csv header")
    header = rows[0]
    fixed_head, fixed_tail = ["sample", "frame", "field", "time_s"], ["error_px", "attempts", "status"]
    if header[:4] != fixed_head or header[-3:] != fixed_tail or len(header) < 8:
        raise ValueError(f"{path}: header {header} is not an angles.csv header (FORMATS §3)")
    names = header[4:-3]
    body: Sequence[list[str]] = rows[1:]

    def num(cell: str) -> float:
        return math.nan if cell == "" else float(cell)

    return AnglesTable(
        dof_names=names,
        samples=np.array([int(r[0]) for r in body], dtype=np.int64),
        frames=np.array([int(r[1]) for r in body], dtype=np.int64),
        fields=[r[2] for r in body],
        times=np.array([float(r[3]) for r in body]),
        dofs=np.array([[num(c) for c in r[4:-3]] for r in body]).reshape(len(body), len(names)),
        errors=np.array([num(r[-3]) for r in body]),
        attempts=np.array([int(r[-2]) for r in body], dtype=np.int64),
        statuses=[Status(r[-1]) for r in body],
    )
