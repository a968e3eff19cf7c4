"""Names and free metadata on uploads, jobs, batches and trials: bounded (422 naming the field),
shown back, carried into report.json (with upload names and ids, never storage keys) and into
the batch archive's folder names (sanitised, unique for trials of the same name)."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import PurePosixPath

import pytest
from sqlalchemy import text
from svc_helpers import upload_inputs, wait_for

from core.examples import LOCUST

pytestmark = [pytest.mark.service]

META = {"subject": "locust 7", "condition": "walking", "trial": {"day": 3, "tags": ["a", "b"]}}
FAST = {"marker_diameter_px": 4.0, "chunk_size": 40, "iterations": 2000}


@pytest.fixture(params=["embedded", "redis_pg"])
def deployment(request):
    """Each test on SQLite (embedded) and on PostgreSQL."""
    return request.getfixturevalue(request.param)


def test_uploads_keep_their_name_and_metadata(deployment, clip):
    client = deployment.create_lab("labelled")
    labels = {"name": "cam0 walk", "metadata": json.dumps(META)}
    rig = client.post("/rigs", content=(LOCUST / "rig.json").read_bytes(), params=labels,
                      headers={"Content-Type": "application/json"})
    with clip.video.open("rb") as f:
        video = client.post("/videos", files={"file": ("clip.avi", f)}, params=labels)
    for kind, response in (("rigs", rig), ("videos", video)):
        assert response.status_code == 201, response.text
        shown = client.get(f"/{kind}/{response.json()['id']}").json()
        assert (shown["name"], shown["metadata"]) == ("cam0 walk", META)
        assert client.get(f"/{kind}").json()["items"][0] == shown
    assert video.json()["filename"] == "clip.avi"


@pytest.mark.parametrize(("params", "field", "problem"), [
    ({"metadata": json.dumps({"a": {"b": {"c": {"d": [1]}}}})}, "metadata", "5 levels deep"),
    ({"metadata": json.dumps({f"k{i}": "x" * 900 for i in range(5)})}, "metadata", "at most 4096"),
    ({"metadata": json.dumps({"k" * 65: 1})}, "metadata", "65 characters"),
    ({"metadata": json.dumps({"a": "x" * 1001})}, "metadata", "1001 characters"),
    ({"metadata": "[1, 2]"}, "metadata", "object"),
    ({"metadata": "{"}, "metadata", "json"),
    ({"name": "n" * 201}, "name", "200"),
    ({"name": "a\nb"}, "name", "control"),
])
def test_metadata_or_name_out_of_bounds_is_422_naming_it_and_nothing_is_stored(deployment, params, field,
                                                                               problem):
    client = deployment.create_lab("bounds")
    response = client.post("/rigs", content=(LOCUST / "rig.json").read_bytes(), params=params,
                           headers={"Content-Type": "application/json"})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert detail.startswith(f"{field}:") and problem.lower() in detail.lower(), detail
    assert client.get("/rigs").json()["items"] == []


def test_job_and_trial_bodies_out_of_bounds_are_422_naming_the_field(deployment):
    client = deployment.create_lab("body-bounds")
    deep = {"a": {"b": {"c": {"d": [1]}}}}
    job = client.post("/jobs", json={"model_id": 1, "rig_id": 1, "video_ids": [1], "metadata": deep})
    assert job.status_code == 422 and job.json()["detail"].startswith("metadata:"), job.text
    batch = client.post("/batches", json={"model_id": 1, "rig_id": 1, "trials": [
        {"video_ids": [1]}, {"video_ids": [1], "metadata": deep}]})
    assert batch.status_code == 422 and batch.json()["detail"].startswith("trials.1.metadata:"), batch.text
    not_finite = client.post("/jobs", content=b'{"model_id": 1, "rig_id": 1, "video_ids": [1], '
                                              b'"metadata": {"x": NaN}}',
                             headers={"Content-Type": "application/json"})
    assert not_finite.status_code == 422 and "finite" in not_finite.json()["detail"], not_finite.text
    named = client.post("/batches", json={"model_id": 1, "rig_id": 1, "name": "",
                                          "trials": [{"video_ids": [1]}]})
    assert named.status_code == 422 and named.json()["detail"].startswith("name:"), named.text


def test_batch_trials_are_named_in_reports_and_archive_folders(redis_pg, clip):
    """Three trials, two of the same name and one that tries to climb out of its folder: each
    gets a folder of its own, and each report names the trial, batch, model, rig and video by
    id, name and upload name, never by storage key or server path."""
    client = redis_pg.create_lab("named-batch")
    ids = upload_inputs(client, clip.video)
    names = ["walk", "walk", "../../etc/passwd"]
    trials = [{"video_ids": [ids["video_id"]], "name": n, "metadata": {"n": i}} for i, n in enumerate(names)]
    response = client.post("/batches", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                             "options": FAST, "trials": trials, "name": "day 3",
                                             "metadata": META})
    assert response.status_code == 202, response.text
    batch = response.json()
    assert (batch["name"], batch["metadata"]) == ("day 3", META)
    assert [(j["name"], j["metadata"]) for j in batch["jobs"]] == [(n, {"n": i}) for i, n in enumerate(names)]
    for job in batch["jobs"]:
        assert wait_for(client, job["id"])["status"] == "succeeded"

    archive = zipfile.ZipFile(io.BytesIO(client.get(f"/batches/{batch['id']}/archive.zip").content))
    folders = sorted({name.split("/")[0] for name in archive.namelist()})
    job_ids = [j["id"] for j in batch["jobs"]]
    assert folders == [f"trial-000-job-{job_ids[0]}-walk", f"trial-001-job-{job_ids[1]}-walk",
                       f"trial-002-job-{job_ids[2]}-_.._etc_passwd"]
    assert all(".." not in PurePosixPath(n).parts and not n.startswith("/") for n in archive.namelist())

    with redis_pg.db().connect() as conn:
        key = conn.execute(text("SELECT storage_key FROM videos WHERE id = :v"),
                           {"v": ids["video_id"]}).scalar_one()
    storage_root = str(redis_pg.data / "storage")
    for trial, folder in enumerate(folders):
        raw = archive.read(f"{folder}/report.json").decode()
        assert key not in raw and key.split("/")[-1] not in raw and storage_root not in raw
        report = json.loads(raw)
        assert report["job"] == {"id": job_ids[trial], "name": names[trial], "metadata": {"n": trial},
                                 "trial": trial}
        assert report["batch"] == {"id": batch["id"], "name": "day 3", "metadata": META}
        assert report["model"] == {"id": ids["model_id"], "name": "locust_hind_leg", "metadata": None}
        assert report["rig"] == {"id": ids["rig_id"], "name": None, "metadata": None}
        assert [(v["id"], v["filename"]) for v in report["videos"]] == [(ids["video_id"], clip.video.name)]
