"""A job's artifacts drawn and stored without the service running (service.artifacts)."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

from core.anneal import AnnealParams
from core.examples import LOCUST
from core.fit import FitParams
from core.histogram import Histograms
from core.model import KinematicModel
from core.pipeline import FitJob, VideoSource, run_fit
from core.rig import Rig
from core.synth import natural_movements, render_frames, write_video
from service.artifacts import INDEX, listed, render
from service.storage import LocalStorage


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    model, rig = KinematicModel.from_xml(LOCUST / "model.xml"), Rig.from_json(LOCUST / "rig.json")
    video = tmp_path_factory.mktemp("clip") / "clip.avi"
    rng = np.random.default_rng(4)
    truth = natural_movements(model, rig, 6, rng=rng)
    write_video(video, render_frames(model, rig, truth, rng=rng), fps=50.0)
    job = FitJob(VideoSource((video,), rig), model, FitParams(anneal=AnnealParams().with_iterations(2000)))
    start = Histograms.uniform(model)
    return job, start, run_fit(job, start).result


def test_overlay_and_plots_are_stored_and_listed(fitted, tmp_path):
    job, start, result = fitted
    storage = LocalStorage(tmp_path)
    index = render(storage, 7, job, start, result, overlay=True, plots=True)
    assert index["error"] is None
    assert {"overlay/video0.avi", "overlay/contact_sheet.png", "plots/angles.svg"} <= set(index["files"])
    assert listed(storage, 7) == index["files"]
    assert all(storage.exists(f"jobs/7/{name}") for name in index["files"])
    assert listed(storage, 8) == []  # a job that asked for none


def test_a_failed_drawing_is_reported_without_paths_and_the_other_still_drawn(fitted, tmp_path):
    job, start, result = fitted
    copy = tmp_path / "copy.avi"
    shutil.copy(job.source.videos[0], copy)
    gone = replace(job, source=replace(job.source, videos=(copy,)))
    assert len(gone.source) == 6  # probed, as a worker's job is before it finishes
    copy.unlink()  # then the video goes: the overlay cannot decode it
    storage = LocalStorage(tmp_path / "store")
    index = render(storage, 3, gone, start, result, overlay=True, plots=True)
    assert index["error"] == "overlay not drawn (VideoError; the worker's log says why)"
    assert index["files"] == ["plots/angles.png", "plots/angles.svg", "plots/histograms.png",
                              "plots/histograms.svg"]
    assert json.loads(storage.path(f"jobs/3/{INDEX}").read_text()) == index
