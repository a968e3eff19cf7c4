"""`mocap fit --export` and `mocap export`: the exported files agree with angles.csv."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import ezc3d
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.app import app
from core.examples import LOCUST
from core.export import marker_trajectories
from core.model import KinematicModel
from core.results import read_angles_csv

# The MOT and TRC readers of core's export tests (tests/core/test_export.py), whichever
# directory pytest collects first.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))

from test_export import read_mot, read_trc

MODEL = KinematicModel.from_xml(LOCUST / "model.xml")


def _invoke(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


def _fit(video: Path, out: Path, *extra: str):
    return _invoke("fit", video, "--model", LOCUST / "model.xml", "--rig", LOCUST / "rig.json",
                   "--out", out, "--marker-diameter-px", "4", *extra)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> Path:
    clip = tmp_path_factory.mktemp("clip")
    done = _invoke("synth", "--model", LOCUST / "model.xml", "--rig", LOCUST / "rig.json",
                   "--out", clip, "--samples", "12", "--seed", "5")
    assert done.exit_code == 0, done.output
    out = clip / "out"
    done = _fit(clip / "video0.avi", out, "--export", "mot,trc,c3d,detections")
    assert done.exit_code == 0, done.output
    assert "angles.mot, markers.trc, markers.c3d, detections.csv" in done.output
    return out


def test_fit_exports_agree_with_angles_csv(fitted):
    table = read_angles_csv(fitted / "angles.csv")
    _, names, values = read_mot(fitted / "angles.mot")
    assert names == ["time", *MODEL.dof_names]
    np.testing.assert_allclose(values[:, 1:], table.dofs, atol=5e-7)
    _, markers, _, points = read_trc(fitted / "markers.trc")
    np.testing.assert_allclose(points, marker_trajectories(table, MODEL), atol=5e-7)
    c3d = ezc3d.c3d(str(fitted / "markers.c3d"))
    assert c3d["data"]["points"].shape == (4, len(markers), len(table.dofs))


def test_fit_detections_csv_is_what_the_report_counts(fitted):
    report = json.loads((fitted / "report.json").read_text())
    with (fitted / "detections.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    for view, counts in report["detections_per_view"].items():
        per_image = [sum(r["view"] == view and int(r["sample"]) == i for r in rows)
                     for i in range(report["images"])]
        assert per_image == counts["per_image"], view


def test_export_command_writes_metres(fitted, tmp_path):
    done = _invoke("export", fitted / "angles.csv", "--model", LOCUST / "model.xml", "--out", tmp_path,
                   "--to", "trc", "--units", "m")
    assert done.exit_code == 0, done.output
    meta, _, _, points = read_trc(tmp_path / "markers.trc")
    _, _, _, model_units = read_trc(fitted / "markers.trc")
    assert meta["Units"] == "m"
    np.testing.assert_allclose(points, model_units / 1000, atol=1e-9)


@pytest.mark.parametrize(("args", "message"), [
    (["--export", "mot,bvh"], "exports must be some of mot,trc,c3d,detections, got 'mot,bvh'"),
    (["--export", "trc", "--export-units", "ft"], "units must be 'model' or 'm'"),
])
def test_fit_refuses_a_bad_export_before_fitting(tmp_path, args, message):
    done = _fit(tmp_path / "none.avi", tmp_path / "out", *args)
    assert done.exit_code == 2 and message in done.output, done.output
    assert not (tmp_path / "out").exists()
