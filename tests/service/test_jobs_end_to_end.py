"""A rendered clip through the real service: upload, submit, poll, download, check.

Runs against both deployments (``conftest``): PostgreSQL + Redis + a worker process,
and ``mocap serve`` embedded (SQLite + filesystem broker).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from svc_helpers import submit, upload_inputs, wait_for

from core.anneal import AnnealParams
from core.detect import DetectorParams
from core.error import fusion_distance
from core.export import export, write_detections_csv
from core.fit import FitParams
from core.histogram import Histograms
from core.pipeline import FitJob, VideoSource, run_fit, write_outputs
from core.results import read_angles_csv

pytestmark = [pytest.mark.service, pytest.mark.slow]

OPTIONS = {"marker_diameter_px": 4.0, "seed": 5, "chunk_size": 10, "iterations": 35000}


@pytest.fixture(scope="session")
def local_fit(clip, tmp_path_factory) -> Path:
    """``mocap fit``'s steps on the clip, same options and chunking: the reference output."""
    params = FitParams(anneal=AnnealParams().with_iterations(OPTIONS["iterations"]),
                       fusion_px=fusion_distance(OPTIONS["marker_diameter_px"]))
    job = FitJob(VideoSource((clip.video,), clip.rig, DetectorParams()), clip.model, params,
                 seed=OPTIONS["seed"], chunk_size=OPTIONS["chunk_size"])
    out = tmp_path_factory.mktemp("local_fit")
    write_outputs(out, job, run_fit(job, Histograms.uniform(clip.model)))
    write_detections_csv(out / "detections.csv", job.source[0:len(job.source)], clip.rig, job.clock)
    return out


@pytest.fixture(params=["redis_pg", "embedded"])
def deployment(request):
    return request.getfixturevalue(request.param)


def test_clip_fitted_by_workers_matches_truth_and_mocap_fit(deployment, clip, local_fit, tmp_path):
    client = deployment.create_lab("end-to-end")
    ids = upload_inputs(client, clip.video)
    job = wait_for(client, submit(client, ids, **OPTIONS)["id"])
    assert job["status"] == "succeeded", job
    assert job["progress"]["images_total"] == job["progress"]["images_done"] == 40
    assert job["progress"]["chunks_done"] == job["progress"]["chunks_total"] == 4
    assert all(job[t].endswith(("Z", "+00:00")) for t in ("created_at", "started_at", "finished_at"))

    csv = client.get(f"/jobs/{job['id']}/angles.csv")
    assert csv.status_code == 200
    (tmp_path / "angles.csv").write_bytes(csv.content)
    table = read_angles_csv(tmp_path / "angles.csv")
    rmse = np.sqrt(np.mean((table.dofs - clip.truth) ** 2, axis=0))
    assert np.all(rmse < 0.5), rmse
    assert np.mean(table.errors) < 1.0

    # The same chunk code as `mocap fit`: identical files, to the last digit.
    assert csv.text == (local_fit / "angles.csv").read_text()
    histograms = client.get(f"/jobs/{job['id']}/histograms.xml").text
    assert histograms == (local_fit / "histograms.xml").read_text()
    report = client.get(f"/jobs/{job['id']}/report.json").json()
    local_report = json.loads((local_fit / "report.json").read_text())
    for key in ("images", "status", "error_px", "reanalysed", "over_threshold_images", "advice"):
        assert report[key] == local_report[key], key

    # The archive: version 1 the uniform prior, version 2 that prior with this job folded in.
    model_id = ids["model_id"]
    v1 = client.get(f"/models/{model_id}/histograms.xml", params={"version": 1})
    assert v1.text == Histograms.uniform(clip.model).to_xml()
    latest = client.get(f"/models/{model_id}/histograms.xml")
    assert latest.headers["X-Histogram-Version"] == "2"
    assert latest.text == histograms

    archive = zipfile.ZipFile(io.BytesIO(client.get(f"/jobs/{job['id']}/archive.zip").content))
    assert sorted(archive.namelist()) == ["angles.csv", "angles.mot", "detections.csv", "histograms.xml",
                                          "markers.c3d", "markers.trc", "model.xml", "report.json",
                                          "rig.json"]
    assert archive.read("angles.csv").decode() == csv.text
    # The exports for other tools, as `mocap export` writes them from this angles.csv.
    export(tmp_path, ["mot", "trc", "c3d"], table, clip.model)
    for name in ("angles.mot", "markers.trc", "markers.c3d"):
        assert archive.read(name) == (tmp_path / name).read_bytes(), name
    # detections.csv joined from the 4 chunks' = one pass over the whole clip.
    assert archive.read("detections.csv") == (local_fit / "detections.csv").read_bytes()


def test_merged_histograms_equal_the_sequential_eq4_update(redis_pg, clip, tmp_path):
    """Chunks fitted by different processes, merged by counts = one histogram updated image by image."""
    client = redis_pg.create_lab("histograms")
    ids = upload_inputs(client, clip.video)
    job = wait_for(client, submit(client, ids, **{**OPTIONS, "chunk_size": 7})["id"])
    assert job["status"] == "succeeded", job
    (tmp_path / "angles.csv").write_bytes(client.get(f"/jobs/{job['id']}/angles.csv").content)
    table = read_angles_csv(tmp_path / "angles.csv")
    sequential = Histograms.uniform(clip.model)
    for dofs, status in zip(table.dofs, table.statuses, strict=True):
        if status == "ok":
            sequential.update(dofs[clip.model.rotational])
    merged = Histograms.from_xml(client.get(f"/jobs/{job['id']}/histograms.xml").content, clip.model)
    np.testing.assert_array_equal(merged.counts, sequential.counts)
    np.testing.assert_allclose(merged.probs, sequential.probs, atol=1e-6)  # XML keeps 6 decimals
    assert merged.counts[0] == 100 + 40
