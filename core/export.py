"""Fitted results in the files other tools read (layouts: ``docs/INTERCHANGE.md``).

- :func:`write_mot`: OpenSim motion file (``.mot``, STO version 1) of the DOF values:
  a ``time`` column, then one column per DOF in model order, degrees for rotations;
- :func:`write_trc`: the model markers' 3D trajectories (forward kinematics of the fitted
  postures, ``core.model``) as an OpenSim / Motion Analysis ``.trc`` (PathFileType 4);
- :func:`write_c3d`: the same points as a C3D file, through ``ezc3d`` (extra ``export``);
- :func:`write_detections_csv`: the 2D centroids the fit saw, one row per detection.

Images without a posture (status ``no_detections``) are written as missing: ``NaN`` in
the MOT and the TRC, C3D points of NaN (ezc3d writes them with residual -1).
Positions are in model units, or in metres with ``units="m"`` when the model's units are
a length ezc3d and OpenSim know (:data:`METRES_PER_UNIT`).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from core.error import Detections
from core.model import KinematicModel
from core.results import AnglesTable, SampleClock
from core.rig import Rig

__all__ = [
    "DETECTIONS_FILE", "DETECTIONS_HEADER", "EXPORTS", "EXPORT_FILES", "METRES_PER_UNIT", "export",
    "marker_trajectories", "unit_scale", "write_c3d", "write_detections_csv", "write_mot", "write_trc",
]

EXPORTS = ("mot", "trc", "c3d", "detections")
METRES_PER_UNIT = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "um": 1e-6, "µm": 1e-6}
# Decimals of positions in model units; angles.csv's DOF precision. In metres, 3 more per
# factor of 1000, so a millimetre model keeps its 1e-6 mm.
DECIMALS = 6


def write_mot(path: Path, table: AnglesTable, model: KinematicModel, *, units: str = "model") -> None:
    """Write the DOF values of ``table`` as an OpenSim motion file (tab-separated).

    Rotational DOFs in degrees (``inDegrees=yes``); root translations in ``units``.
    """
    _check_table(table, model)
    scale, _ = unit_scale(model, units)
    values = np.where(model.rotational, table.dofs, table.dofs * scale)
    decimals = np.where(model.rotational, DECIMALS, _decimals(scale))
    header = [path.stem, "version=1", f"nRows={len(table.times)}", f"nColumns={len(model.dofs) + 1}",
              "inDegrees=yes", "endheader"]
    with path.open("w", newline="") as fh:
        fh.write("\n".join(header) + "\n")
        fh.write("\t".join(["time", *model.dof_names]) + "\n")
        for t, row in zip(table.times, values, strict=True):
            cells = [_fmt(v, int(d)) for v, d in zip(row, decimals, strict=True)]
            fh.write("\t".join([f"{t:.6f}", *(c or "NaN" for c in cells)]) + "\n")


def marker_trajectories(table: AnglesTable, model: KinematicModel) -> np.ndarray:
    """World positions of the model markers in every fitted image.

    Returns
    -------
    ndarray of shape (T, M, 3), float64, model units; NaN for images without a posture.
    """
    _check_table(table, model)
    out = np.full((len(table.dofs), len(model.markers), 3), np.nan)
    posed = np.all(np.isfinite(table.dofs), axis=1)
    if posed.any():
        out[posed] = model.marker_positions(table.dofs[posed]).reshape(-1, len(model.markers), 3)
    return out


def write_trc(path: Path, table: AnglesTable, model: KinematicModel, *, units: str = "model") -> None:
    """Write the markers' trajectories as a TRC file (PathFileType 4, tab-separated).

    ``Frame#`` counts the images from 1; ``Time`` is ``time_s``; missing markers are ``NaN``
    (OpenSim's reader needs a value in every cell).
    """
    scale, unit = unit_scale(model, units)
    points = marker_trajectories(table, model) * scale
    rate = _rate(table.times)
    n, m = points.shape[:2]
    decimals = _decimals(scale)
    names = [mk.name for mk in model.markers]
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate:.6f}\t{rate:.6f}\t{n}\t{m}\t{unit}\t{rate:.6f}\t1\t{n}",
        "\t".join(["Frame#", "Time", *(f"{name}\t\t" for name in names)]).rstrip("\t"),
        "\t".join(["", "", *(f"X{i}\tY{i}\tZ{i}" for i in range(1, m + 1))]),
        "",
    ]
    with path.open("w", newline="") as fh:
        fh.write("\n".join(lines) + "\n")
        for k in range(n):
            cells = [_fmt(v, decimals) or "NaN" for v in points[k].ravel()]
            fh.write("\t".join([str(k + 1), f"{table.times[k]:.6f}", *cells]) + "\n")


def write_c3d(path: Path, table: AnglesTable, model: KinematicModel, *, units: str = "model") -> None:
    """Write the markers' trajectories as a C3D file (``ezc3d``; POINT:UNITS the unit).

    C3D stores 32-bit floats: positions round-trip to about 7 significant digits.
    """
    try:
        import ezc3d  # an optional extra: the C3D binary layout is ezc3d's job
    except ImportError:
        raise ValueError("C3D export needs ezc3d: pip install 'mocap[export]'") from None
    scale, unit = unit_scale(model, units)
    points = marker_trajectories(table, model) * scale
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = np.array([_rate(table.times)])
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(mk.name for mk in model.markers)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = [unit]
    data = np.ones((4, points.shape[1], points.shape[0]))
    data[:3] = points.transpose(2, 1, 0)
    c3d["data"]["points"] = data
    c3d.write(str(path))


DETECTIONS_FILE = "detections.csv"
DETECTIONS_HEADER = ["sample", "frame", "field", "time_s", "view", "u", "v", "area_px"]


def write_detections_csv(
    out: Path | TextIO, detections: Iterable[Detections], rig: Rig, clock: SampleClock, *,
    first_sample: int = 0, header: bool = True,
) -> int:
    """Write every detected centroid, one row per detection, in sample then view order.

    detections : one :class:`~core.error.Detections` per analysed image, from ``first_sample``.
    Columns: :data:`DETECTIONS_HEADER` (``header=False`` leaves the header line out, for a
    chunk of a longer file); ``u``, ``v`` full-frame pixels (FORMATS §2), 4 decimals;
    ``area_px`` the detected region's pixels (empty when unknown). A view that saw nothing in
    an image has no row for it. Returns the number of images written.
    """
    if isinstance(out, Path):
        with out.open("w", newline="") as fh:
            return write_detections_csv(fh, detections, rig, clock, first_sample=first_sample,
                                        header=header)
    names = [v.name for v in rig.views]
    count = 0
    writer = csv.writer(out, lineterminator="\n")
    if header:
        writer.writerow(DETECTIONS_HEADER)
    for sample, det in enumerate(detections, start=first_sample):
        head = [sample, clock.frame(sample), clock.field(sample), f"{clock.time(sample):.6f}"]
        for v, name in enumerate(names):
            for i in range(int(det.start[v]), int(det.start[v + 1])):
                area = "" if det.areas is None else _fmt(float(det.areas[i]), 1)
                u, w = det.points[i]
                writer.writerow([*head, name, f"{u:.4f}", f"{w:.4f}", area])
        count += 1
    return count


# ---- helpers ----------------------------------------------------------------------------------


def _check_table(table: AnglesTable, model: KinematicModel) -> None:
    if table.dof_names != model.dof_names:
        raise ValueError(f"angles.csv has DOF columns {table.dof_names}, the model {model.dof_names}")


def unit_scale(model: KinematicModel, units: str) -> tuple[float, str]:
    """(factor from model units, unit name) for ``units`` 'model' or 'm'; ValueError otherwise."""
    if units == "model":
        return 1.0, model.units
    if units != "m":
        raise ValueError(f"units must be 'model' or 'm', got {units!r}")
    if model.units not in METRES_PER_UNIT:
        raise ValueError(f"the model's units '{model.units}' are not a length this export knows "
                         f"({', '.join(METRES_PER_UNIT)}): export in model units instead")
    return METRES_PER_UNIT[model.units], "m"


def _decimals(scale: float) -> int:
    return DECIMALS + max(0, round(-math.log10(scale)))


def _rate(times: np.ndarray) -> float:
    """Images per second from ``time_s`` (de-interlaced: fields per second); 0 for one image."""
    if len(times) < 2 or times[-1] <= times[0]:
        return 0.0
    return float((len(times) - 1) / (times[-1] - times[0]))


def _fmt(value: float, decimals: int) -> str:
    return f"{value:.{decimals}f}" if math.isfinite(value) else ""


# The file each export of the fitted angles is written to by :func:`export`.
EXPORT_FILES = {"mot": "angles.mot", "trc": "markers.trc", "c3d": "markers.c3d"}


def export(
    out: Path, kinds: Sequence[str], table: AnglesTable, model: KinematicModel, *, units: str = "model",
) -> list[Path]:
    """Write the exports ``kinds`` (of mot, trc, c3d) of ``table`` into ``out`` under the names
    of :data:`EXPORT_FILES`; return their paths."""
    writers = {"mot": write_mot, "trc": write_trc, "c3d": write_c3d}
    paths = []
    for kind in kinds:
        if kind not in writers:
            raise ValueError(f"unknown export {kind!r}; use {', '.join(writers)}")
        writers[kind](out / EXPORT_FILES[kind], table, model, units=units)
        paths.append(out / EXPORT_FILES[kind])
    return paths
