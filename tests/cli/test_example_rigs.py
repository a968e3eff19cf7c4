"""The rig examples of docs/RIGS.md: each kind fits the locust leg's setup and is fitted back."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.app import app
from core.calibration import from_dlt
from core.examples import LOCUST
from core.model import KinematicModel
from core.results import read_angles_csv
from core.rig import Rig
from core.synth import read_truth_csv

MODEL = KinematicModel.from_xml(LOCUST / "model.xml")
NEW_RIGS = ["rig_pinhole.json", "rig_dlt.json"]  # rig.json is the paper's, tested elsewhere


def test_the_dlt_example_is_the_import_of_its_coefficients():
    """To the last bits NumPy's linear algebra leaves, which differ between CPUs (OpenBLAS
    picks its code for the one it runs on)."""
    committed = Rig.from_json(LOCUST / "rig_dlt.json")
    imported = from_dlt(LOCUST / "cal_dltCoefs.csv", heights=[576])
    assert committed.frames == imported.frames
    assert [(v.name, v.video, v.roi, v.projection["type"]) for v in committed.views] == \
        [(v.name, v.video, v.roi, v.projection["type"]) for v in imported.views]
    for a, b in zip(committed.views, imported.views, strict=True):
        np.testing.assert_allclose(a.projection["P"], b.projection["P"], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", NEW_RIGS)
def test_every_posture_in_range_is_seen_inside_the_frame(name):
    rig = Rig.from_json(LOCUST / name)
    postures = np.random.default_rng(0).uniform(MODEL.lower, MODEL.upper, (2000, len(MODEL.dofs)))
    uv = rig.project(MODEL.marker_positions(postures).reshape(-1, 3))
    for v, view in enumerate(rig.views):
        assert np.all((uv[v] > 10) & (uv[v] < [720 - 10, 576 - 10])), view.name


@pytest.mark.parametrize("name", NEW_RIGS)
def test_a_clip_rendered_through_the_example_is_fitted_back(tmp_path, name):
    rig = Rig.from_json(LOCUST / name)
    run = CliRunner()
    done = run.invoke(app, ["synth", "--model", str(LOCUST / "model.xml"), "--rig", str(LOCUST / name),
                            "--out", str(tmp_path), "--samples", "10", "--seed", "2"])
    assert done.exit_code == 0, done.output
    videos = [str(tmp_path / f"video{k}.avi") for k in range(rig.n_videos)]
    done = run.invoke(app, ["fit", *videos, "--model", str(LOCUST / "model.xml"),
                            "--rig", str(LOCUST / name), "--out", str(tmp_path / "out"),
                            "--marker-diameter-px", "4"])
    assert done.exit_code == 0, done.output
    _, truth = read_truth_csv(tmp_path / "truth.csv")
    fitted = read_angles_csv(tmp_path / "out" / "angles.csv").dofs
    assert np.sqrt(np.mean((fitted - truth) ** 2, axis=0)).max() < 0.5
