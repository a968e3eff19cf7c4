"""Overlay and plot artifacts of a job, and the synchronous detection preview, over HTTP."""

from __future__ import annotations

import base64
import io
import zipfile

import cv2
import defusedxml.ElementTree as SafeET
import numpy as np
import pytest
from svc_helpers import submit, upload_inputs, wait_for
from typer.testing import CliRunner

from cli.app import app
from core.detect import DetectorParams, detect, threshold_level, view_images
from core.video import VideoSet

pytestmark = [pytest.mark.service, pytest.mark.slow]

OPTIONS = {"marker_diameter_px": 4.0, "chunk_size": 20, "iterations": 5000}


@pytest.fixture(scope="module")
def lab(redis_pg, clip):
    client = redis_pg.create_lab("see-fit")
    return client, upload_inputs(client, clip.video)


def test_a_job_asked_for_overlay_and_plots_serves_and_archives_them(redis_pg, lab, clip, tmp_path):
    client, ids = lab
    job = wait_for(client, submit(client, ids, overlay=True, plots=True, **OPTIONS)["id"])
    assert job["status"] == "succeeded", job
    names = client.get(f"/jobs/{job['id']}/artifacts").json()
    assert {"overlay/video0.avi", "overlay/contact_sheet.png", "overlay/overlay.json", "plots/angles.png",
            "plots/angles.svg", "plots/histograms.png", "plots/histograms.svg"} <= set(names)
    assert sum(n.startswith("overlay/images/") for n in names) == 12

    sheet = client.get(f"/jobs/{job['id']}/artifacts/overlay/contact_sheet.png")
    assert sheet.status_code == 200 and sheet.headers["content-type"] == "image/png"
    assert cv2.imdecode(np.frombuffer(sheet.content, np.uint8), cv2.IMREAD_COLOR).shape[1] == 4 * 320
    svg = client.get(f"/jobs/{job['id']}/artifacts/plots/angles.svg")
    assert svg.headers["content-type"].startswith("image/svg+xml")
    SafeET.fromstring(svg.content)
    manifest = client.get(f"/jobs/{job['id']}/artifacts/overlay/overlay.json").json()
    first = client.get(f"/jobs/{job['id']}/artifacts/overlay/{manifest['images'][0]['file']}")
    assert first.status_code == 200 and first.content[:8] == b"\x89PNG\r\n\x1a\n"
    report = client.get(f"/jobs/{job['id']}/report.json").json()
    assert report["artifacts"] == {"files": names, "error": None}

    archive = zipfile.ZipFile(io.BytesIO(client.get(f"/jobs/{job['id']}/archive.zip").content))
    assert {"angles.csv", "model.xml", *names} <= set(archive.namelist())
    assert archive.read("plots/angles.svg") == svg.content
    # The unpacked archive is a results directory: `mocap overlay` redraws the worker's images.
    archive.extractall(tmp_path / "job")
    again = CliRunner().invoke(app, ["overlay", str(tmp_path / "job"), str(clip.video), "--worst", "3"])
    assert again.exit_code == 0, again.output
    for item in manifest["images"][:3]:
        file = f"overlay/{item['file']}"
        assert (tmp_path / "job" / file).read_bytes() == archive.read(file)

    for bad in ("angles.csv", "plots/nothing.png", "overlay/images/sample_999999.png", "overlay/x/../a.png"):
        response = client.get(f"/jobs/{job['id']}/artifacts/{bad}")
        assert response.status_code == 404, bad
        assert response.json()["detail"].startswith(f"job {job['id']} has no artifact"), bad
    other = redis_pg.create_lab("see-fit other")
    assert other.get(f"/jobs/{job['id']}/artifacts").status_code == 404
    assert other.get(f"/jobs/{job['id']}/artifacts/plots/angles.svg").status_code == 404


def test_a_job_without_the_options_has_no_artifacts(lab):
    client, ids = lab
    job = wait_for(client, submit(client, ids, **OPTIONS)["id"])
    assert job["status"] == "succeeded", job
    assert client.get(f"/jobs/{job['id']}/artifacts").json() == []
    assert client.get(f"/jobs/{job['id']}/artifacts/plots/angles.svg").status_code == 404
    assert "artifacts" not in client.get(f"/jobs/{job['id']}/report.json").json()


def test_detect_preview_gives_core_detects_counts_on_one_frame(redis_pg, lab, clip):
    client, ids = lab
    response = client.post(f"/videos/{ids['video_id']}/detect-preview",
                           json={"rig_id": ids["rig_id"], "frame": 7, "detector": {"threshold": 90}})
    assert response.status_code == 200, response.text
    body = response.json()
    (frames,) = VideoSet([clip.video]).read(7, 8)
    expected = detect(frames, rig=clip.rig, params=DetectorParams(threshold=90))
    assert body["counts"] == {"side": int(expected.counts[0]), "top": int(expected.counts[1])}
    assert body["thresholds"] == {"side": 90.0, "top": 90.0}
    np.testing.assert_allclose(body["centroids"]["side"], expected.view(0), atol=1e-3)
    picked = client.post(f"/videos/{ids['video_id']}/detect-preview",
                         json={"rig_id": ids["rig_id"], "frame": 7})  # the default 'auto'
    assert picked.status_code == 200, picked.text
    views = view_images(frames, clip.rig, DetectorParams())
    assert picked.json()["thresholds"] == {"side": threshold_level(views[0], DetectorParams()),
                                           "top": threshold_level(views[1], DetectorParams())}
    png = base64.b64decode(body["image"].removeprefix("data:image/png;base64,"))
    assert cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).shape == frames[0].shape


@pytest.mark.parametrize(("body", "status", "match"), [
    ({"frame": 40}, 422, "frame 40 is past the 40 frames of video"),
    ({"video_index": 1}, 422, "has no view in video 1"),
    ({"detector": {"min_area": 10, "max_area": 5}}, 422, "max_area"),
    ({"rig_id": 99999}, 404, ""),
])
def test_detect_preview_bad_input(redis_pg, lab, body, status, match):
    client, ids = lab
    response = client.post(f"/videos/{ids['video_id']}/detect-preview",
                           json={"rig_id": ids["rig_id"], **body})
    assert response.status_code == status, response.text
    assert match in str(response.json()["detail"])
    other = redis_pg.create_lab("see-fit preview other")
    assert other.post(f"/videos/{ids['video_id']}/detect-preview",
                      json={"rig_id": ids["rig_id"]}).status_code == 404
