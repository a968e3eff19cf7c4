"""Render → lossless video → read back → detect → fit, against the ground truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from typer.testing import CliRunner

from cli.app import app
from core.detect import detect
from core.examples import EXAMPLES
from core.fit import FitParams, Status
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig
from core.sequence import fit_sequence
from core.synth import natural_movements, render_frames, write_video


def _read_grey(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame)
    cap.release()
    return frames


def _fit_rendered_clip(tmp_path, example: str, n: int = 60):
    model = KinematicModel.from_xml(EXAMPLES / example / "model.xml")
    rig = Rig.from_json(EXAMPLES / example / "rig.json")
    rng = np.random.default_rng(11)
    truth = natural_movements(model, rig, n, rng=rng, n_sequences=2)
    video = tmp_path / "clip.avi"
    assert write_video(video, render_frames(model, rig, truth, rng=rng), fps=50.0) == n
    frames = _read_grey(video)
    assert len(frames) == n
    detections = [detect([f], rig=rig) for f in frames]
    result = fit_sequence(detections, model=model, rig=rig, histograms=Histograms.uniform(model),
                          params=FitParams(fusion_px=4.0), seed=5)
    fitted = np.array([f.dofs for f in result.fits])
    return model, result, np.abs(fitted - truth)


def test_locust_clip_within_the_both_view_targets(tmp_path):
    """Two views, 4 px markers, noise: every DOF RMSE < 0.5 degree, mean view error < 1 px."""
    model, result, err = _fit_rendered_clip(tmp_path, "locust_hind_leg")
    rmse = np.sqrt(np.mean(err**2, axis=0))
    assert np.all(rmse < 0.5), dict(zip(model.dof_names, rmse.round(3), strict=True))
    assert np.mean([f.error for f in result.fits]) < 1.0
    assert all(f.status is Status.OK for f in result.fits)


def test_stick_insect_clip_within_bounds(tmp_path):
    """Median error < 0.1 degree; at most 5 % of images more than 2 degrees off.

    The femur and tibia markers fuse with the body markers in some postures,
    where two postures explain the blobs equally well (the paper's Fig. 9).
    """
    model, result, err = _fit_rendered_clip(tmp_path, "stick_insect_front_leg")
    median = np.median(err, axis=0)
    assert np.all(median < 0.1), dict(zip(model.dof_names, median.round(3), strict=True))
    assert np.mean(err.max(axis=1) > 2.0) <= 0.05
    assert np.median([f.error for f in result.fits]) < 1.0


def test_demo_command_prints_accuracy():
    result = CliRunner().invoke(app, ["demo", "--samples", "12"])
    assert result.exit_code == 0, result.output
    assert "RMSE against the truth" in result.output
    assert "phi" in result.output and "mean view error" in result.output
    assert "fitting kernels ready in" in result.output  # the first run's compile is announced


def test_demo_rejects_bad_option():
    result = CliRunner().invoke(app, ["demo", "--samples", "0"])
    assert result.exit_code == 2
