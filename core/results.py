"""The per-sample tables: ``angles.csv`` (FORMATS §3), the true postures of a rendered clip
(``truth.csv``, the same leading columns), and the timing of samples.

Columns: ``sample,frame,field,time_s,<dof names in model order>,error_px,attempts,status``,
then FORMATS §3's two optional columns, always written here:
``error_per_marker_px`` (``error_px`` per compared marker projection, what the threshold
is compared with) and ``alternative_deg`` (empty, or how far in degrees the best distinct
alternative posture lies: the image is ambiguous). DOFs are reported in their own range
(no wrapping), C-locale decimals. An image without detections has empty DOF and error
cells: there is no posture to report.

``truth.csv`` has the same leading columns and the DOFs, nothing else:
``sample,frame,field,time_s,<dof names>``, numbers written exactly (shortest decimals that
read back to the same float), so that a rendered clip's truth survives the file.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from core._checks import check_positive, check_trajectory
from core._files import decimal
from core.fields import field_parities
from core.fit import ImageFit, Status
from core.model import KinematicModel

__all__ = ["SampleClock", "angles_header", "read_angles_csv", "read_truth_csv", "write_angles_csv",
           "write_truth_csv"]


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


SAMPLE_COLUMNS = ["sample", "frame", "field", "time_s"]  # both tables begin with them
_FIXED_TAIL = ["error_px", "attempts", "status"]
OPTIONAL_COLUMNS = ["error_per_marker_px", "alternative_deg"]


def angles_header(model: KinematicModel) -> list[str]:
    return [*SAMPLE_COLUMNS, *model.dof_names, *_FIXED_TAIL, *OPTIONAL_COLUMNS]


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
    n_markers, rotational = len(model.markers), model.rotational
    for f in fits:
        writer.writerow(
            [f.sample, clock.frame(f.sample), clock.field(f.sample), f"{clock.time(f.sample):.6f}",
             *(_cell(v, 6) for v in f.dofs), _cell(f.error, 4), f.attempts, f.status.value,
             _cell(f.error_per_marker(n_markers), 4), _cell(f.alternative_deg(rotational), 3)]
        )


def _cell(value: float, decimals: int) -> str:
    return "" if not math.isfinite(value) else f"{value:.{decimals}f}"


@dataclass(frozen=True)
class AnglesTable:
    """angles.csv read back: DOF values (N, D) with NaN for empty cells, and the other columns.

    ``error_per_marker`` and ``alternative_deg`` are NaN where the file leaves them
    empty or lacks the optional columns.
    """

    dof_names: list[str]
    samples: np.ndarray
    frames: np.ndarray
    fields: list[str]
    times: np.ndarray
    dofs: np.ndarray
    errors: np.ndarray
    attempts: np.ndarray
    statuses: list[Status]
    error_per_marker: np.ndarray
    alternative_deg: np.ndarray


def read_angles_csv(path: Path) -> AnglesTable:
    """Read an ``angles.csv`` written by :func:`write_angles_csv` (or any FORMATS §3 file)."""
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path.name}: empty file, expected an angles.csv header")
    header = rows[0]
    try:
        status_at = len(header) - 1 - header[::-1].index("status")
    except ValueError:
        status_at = -1
    names = header[4:status_at - 2]
    if header[:4] != SAMPLE_COLUMNS or status_at < 7 \
            or header[status_at - 2:status_at + 1] != _FIXED_TAIL:
        raise ValueError(f"{path.name}: header {header} is not an angles.csv header (FORMATS §3)")
    extra = header[status_at + 1:]
    body: Sequence[list[str]] = rows[1:]

    def num(cell: str) -> float:
        return math.nan if cell == "" else float(cell)

    def optional(name: str) -> np.ndarray:
        if name not in extra:
            return np.full(len(body), np.nan)
        k = status_at + 1 + extra.index(name)
        return np.array([num(r[k]) for r in body])

    return AnglesTable(
        dof_names=names,
        samples=np.array([int(r[0]) for r in body], dtype=np.int64),
        frames=np.array([int(r[1]) for r in body], dtype=np.int64),
        fields=[r[2] for r in body],
        times=np.array([float(r[3]) for r in body]),
        dofs=np.array([[num(c) for c in r[4:status_at - 2]] for r in body]).reshape(len(body), len(names)),
        errors=np.array([num(r[status_at - 2]) for r in body]),
        attempts=np.array([int(r[status_at - 1]) for r in body], dtype=np.int64),
        statuses=[Status(r[status_at]) for r in body],
        error_per_marker=optional("error_per_marker_px"),
        alternative_deg=optional("alternative_deg"),
    )


# ---- truth.csv ---------------------------------------------------------------------------------


def write_truth_csv(
    path: str | Path,
    model: KinematicModel,
    trajectory: np.ndarray,
    *,
    fps: float,
    interlaced: bool,
) -> None:
    """Write the true postures as CSV: ``sample,frame,field,time_s,<dof names>``.

    Columns mean what they mean in ``angles.csv`` (FORMATS §3): ``sample`` is the
    0-based sample (frame, or field when ``interlaced``), ``frame`` the video
    frame, ``field`` ``even``/``odd`` when interlaced and empty otherwise,
    ``time_s`` seconds from the start of the video, then one column per DOF in
    model-file order (degrees, model units). Numbers are C-locale decimals
    without exponents, written with the shortest digits that read back exactly.

    Parameters
    ----------
    path : str or Path
    model : KinematicModel
    trajectory : ndarray of shape (T, D), float64, model-file DOF order.
    fps : float
        Video frame rate, > 0 (fields are 1 / (2 fps) apart when interlaced).
    interlaced : bool
        True if samples are fields: sample 2k is frame k's even field, 2k+1 its odd field.
    """
    q = check_trajectory(trajectory, model)
    clock = SampleClock(fps=check_positive("fps", fps), deinterlaced=bool(interlaced))
    with Path(path).open("w", newline="") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow([*SAMPLE_COLUMNS, *model.dof_names])
        for s, row in enumerate(q):
            writer.writerow(
                [s, clock.frame(s), clock.field(s), decimal(clock.time(s)),
                 *(decimal(v) for v in row)]
            )


def read_truth_csv(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Read a truth CSV written by :func:`write_truth_csv`.

    Returns
    -------
    names : list of str
        DOF names, in column (model-file) order.
    dofs : ndarray of shape (T, D), float64
        True DOF values, one row per sample, in sample order.

    Raises
    ------
    ValueError
        If the header is not ``sample,frame,field,time_s,<dofs>``, or a cell is not a number.
    """
    path = Path(path)
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or rows[0][:4] != SAMPLE_COLUMNS or len(rows[0]) < 5:
        head = rows[0] if rows else []
        raise ValueError(f"{path}: header {head} is not 'sample,frame,field,time_s,<dof names>'")
    names = rows[0][4:]
    values = np.empty((len(rows) - 1, len(names)), dtype=np.float64)
    for i, row in enumerate(rows[1:]):
        if len(row) != len(names) + 4:
            raise ValueError(
                f"{path}: line {i + 2} has {len(row)} cells, expected {len(names) + 4}"
            )
        try:
            values[i] = [float(c) for c in row[4:]]
        except ValueError:
            raise ValueError(f"{path}: line {i + 2} has a DOF cell that is not a number") from None
    return names, values
