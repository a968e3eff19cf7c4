"""`mocap rig import`: a calibration file in, rig.json out, one line on error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from cli.app import app
from core.calibration import from_anipose
from core.rig import Rig

DATA = Path(__file__).parents[1] / "data"


def test_rig_import_writes_the_rig(tmp_path):
    out = tmp_path / "rig.json"
    result = CliRunner().invoke(app, ["rig", "import", "anipose", str(DATA / "anipose_calibration.toml"),
                                      "--out", str(out), "--video-index", "0,1,0"])
    assert result.exit_code == 0, result.output
    rig = Rig.from_json(out)
    assert [(v.name, v.video) for v in rig.views] == [("left", 0), ("front", 1), ("right", 0)]
    points = np.random.default_rng(0).uniform(-20, 20, (10, 3))
    np.testing.assert_array_equal(rig.project(points),
                                  from_anipose(DATA / "anipose_calibration.toml").project(points))


def test_rig_import_dlt_with_heights(tmp_path):
    coefs = tmp_path / "cal_dltCoefs.csv"
    coefs.write_text("1,2\n0,0\n0,0\n0,0\n0,0\n1,1\n0,0\n0,0\n0,0\n0,0\n1,1\n")
    out = tmp_path / "rig.json"
    result = CliRunner().invoke(app, ["rig", "import", "dlt", str(coefs), "--out", str(out),
                                      "--height", "480,600"])
    assert result.exit_code == 0, result.output
    rig = Rig.from_json(out)
    assert [v.projection["P"][1][3] for v in rig.views] == [480.5, 600.5]


def _mocap(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "service.cli", *args], capture_output=True, text=True)


def test_rig_import_errors_are_one_line_and_exit_2(tmp_path):
    for args, message in [
        (["anipose", str(DATA / "anipose_fisheye.toml")], "is a fisheye camera"),
        (["dlt", str(DATA / "anipose_calibration.toml")], "give each camera's image height"),
        (["dlt", str(DATA / "anipose_calibration.toml"), "--height", "x"],
         "--height must be comma-separated"),
        (["anipose", str(DATA / "anipose_calibration.toml"), "--video-index", "0,-1,2"],
         "--video-index must be whole numbers >= 0"),
        (["vicon", str(DATA / "anipose_calibration.toml")], "unknown calibration format 'vicon'"),
        (["anipose", str(tmp_path / "missing.toml")], "cannot read missing.toml"),
    ]:
        done = _mocap("rig", "import", *args, "--out", str(tmp_path / "rig.json"))
        assert done.returncode == 2, (args, done.stderr)
        assert done.stderr.startswith("mocap: error: ") and done.stderr.count("\n") == 1, done.stderr
        assert message in done.stderr, done.stderr
    assert not (tmp_path / "rig.json").exists()
