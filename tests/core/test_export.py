"""Exports (core.export): each file read back, values equal to their printed precision."""

from __future__ import annotations

import csv
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from core.error import Detections
from core.examples import LOCUST
from core.export import (
    marker_trajectories,
    write_c3d,
    write_detections_csv,
    write_mot,
    write_trc,
)
from core.fit import Status
from core.model import KinematicModel
from core.results import AnglesTable, SampleClock
from core.rig import Rig

MODEL = KinematicModel.from_xml(LOCUST / "model.xml")


def angles_table(model: KinematicModel, n: int = 12, *, fps: float = 50.0, seed: int = 0) -> AnglesTable:
    """Postures drawn inside the ranges; image 3 without detections (NaN), like angles.csv."""
    rng = np.random.default_rng(seed)
    dofs = rng.uniform(model.lower, model.upper, (n, len(model.dofs)))
    dofs[3] = np.nan
    status = [Status.NO_DETECTIONS if i == 3 else Status.OK for i in range(n)]
    return AnglesTable(model.dof_names, np.arange(n), np.arange(n), [""] * n, np.arange(n) / fps, dofs,
                       np.zeros(n), np.ones(n, dtype=np.int64), status, np.zeros(n),
                       np.full(n, np.nan))


def read_mot(path: Path) -> tuple[dict[str, str], list[str], np.ndarray]:
    """A small reader of OpenSim's motion files: header keys, column names, values."""
    lines = path.read_text().splitlines()
    end = lines.index("endheader")
    header = dict(line.split("=", 1) for line in lines[1:end] if "=" in line)
    names = lines[end + 1].split("\t")
    return header, names, np.array([[float(c) for c in line.split("\t")] for line in lines[end + 2:]])


def read_trc(path: Path) -> tuple[dict[str, str], list[str], np.ndarray, np.ndarray]:
    """A small TRC reader: the metadata of lines 2-3, marker names, times and (T, M, 3) positions."""
    lines = path.read_text().split("\n")
    assert lines[0].split("\t")[:3] == ["PathFileType", "4", "(X/Y/Z)"]
    meta = dict(zip(lines[1].split("\t"), lines[2].split("\t"), strict=True))
    markers = [c for c in lines[3].split("\t")[2:] if c]
    assert lines[4].split("\t")[2:5] == ["X1", "Y1", "Z1"] and lines[5] == ""
    rows = np.array([[float(c) for c in line.split("\t")] for line in lines[6:] if line])
    assert np.array_equal(rows[:, 0], np.arange(1, len(rows) + 1))
    return meta, markers, rows[:, 1], rows[:, 2:].reshape(len(rows), len(markers), 3)


def test_mot_holds_the_dofs_in_degrees(tmp_path):
    table = angles_table(MODEL)
    write_mot(tmp_path / "angles.mot", table, MODEL)
    header, names, values = read_mot(tmp_path / "angles.mot")
    assert header == {"version": "1", "nRows": "12", "nColumns": "6", "inDegrees": "yes"}
    assert names == ["time", *MODEL.dof_names]
    np.testing.assert_allclose(values[:, 0], table.times, atol=5e-7)
    np.testing.assert_allclose(values[:, 1:], table.dofs, atol=5e-7)  # NaN where NaN
    assert np.isnan(values[3, 1:]).all()


def test_trc_holds_the_model_markers(tmp_path):
    table = angles_table(MODEL)
    write_trc(tmp_path / "markers.trc", table, MODEL)
    meta, markers, times, points = read_trc(tmp_path / "markers.trc")
    assert meta["Units"] == "mm" and float(meta["DataRate"]) == 50.0
    assert meta["NumFrames"] == "12" and meta["NumMarkers"] == "4"
    assert markers == [m.name for m in MODEL.markers]
    np.testing.assert_allclose(times, table.times, atol=5e-7)
    expected = MODEL.marker_positions(np.nan_to_num(table.dofs))
    expected[3] = np.nan
    np.testing.assert_allclose(points, expected, atol=5e-7)


def test_trc_in_metres(tmp_path):
    table = angles_table(MODEL)
    write_trc(tmp_path / "markers.trc", table, MODEL, units="m")
    meta, _, _, points = read_trc(tmp_path / "markers.trc")
    assert meta["Units"] == "m"
    np.testing.assert_allclose(points, marker_trajectories(table, MODEL) / 1000, atol=5e-10)


def test_metres_need_a_known_length_unit(tmp_path):
    model = KinematicModel.from_xml((LOCUST / "model.xml").read_text().replace('units="mm"', 'units="px"'))
    with pytest.raises(ValueError, match="the model's units 'px' are not a length"):
        write_trc(tmp_path / "x.trc", angles_table(model), model, units="m")
    with pytest.raises(ValueError, match="units must be 'model' or 'm'"):
        write_mot(tmp_path / "x.mot", angles_table(model), model, units="inch")


def test_a_table_of_another_model_is_refused(tmp_path):
    table = angles_table(MODEL)
    other = AnglesTable(["a", "b", "c", "d", "e"], *list(vars(table).values())[1:])
    with pytest.raises(ValueError, match=r"angles\.csv has DOF columns"):
        write_mot(tmp_path / "x.mot", other, MODEL)


@pytest.mark.parametrize("units", ["model", "m"])
def test_c3d_read_back_by_ezc3d(tmp_path, units):
    table = angles_table(MODEL, fps=25.0)
    write_c3d(tmp_path / "markers.c3d", table, MODEL, units=units)
    c3d = ezc3d.c3d(str(tmp_path / "markers.c3d"))
    point = c3d["parameters"]["POINT"]
    assert list(point["LABELS"]["value"]) == [m.name for m in MODEL.markers]
    assert point["UNITS"]["value"] == ["mm" if units == "model" else "m"]
    assert point["RATE"]["value"][0] == 25.0
    got = c3d["data"]["points"][:3].transpose(2, 1, 0)
    expected = marker_trajectories(table, MODEL) / (1000 if units == "m" else 1)
    assert np.isnan(got[3]).all()
    # C3D stores 32-bit floats: 7 significant digits.
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-6 * np.nanmax(np.abs(expected)))


def test_detections_csv_lists_every_centroid(tmp_path):
    rig = Rig.from_json(LOCUST / "rig.json")
    images = [
        Detections.from_views([np.array([[10.25, 20.5], [30.0, 40.125]]), np.zeros((0, 2))],
                              [np.array([12.0, 13.0]), np.zeros(0)]),
        Detections.from_views([np.zeros((0, 2)), np.array([[1.23456, 2.5]])], [np.zeros(0), np.array([9.0])]),
    ]
    clock = SampleClock(25.0, deinterlaced=True)
    assert write_detections_csv(tmp_path / "d.csv", images, rig, clock, first_sample=6) == 2
    with (tmp_path / "d.csv").open() as fh:
        rows = list(csv.reader(fh))
    side, top = (v.name for v in rig.views)
    assert rows == [
        ["sample", "frame", "field", "time_s", "view", "u", "v", "area_px"],
        ["6", "3", "even", "0.120000", side, "10.2500", "20.5000", "12.0"],
        ["6", "3", "even", "0.120000", side, "30.0000", "40.1250", "13.0"],
        ["7", "3", "odd", "0.140000", top, "1.2346", "2.5000", "9.0"],
    ]
