"""Tenancy (another lab's ids are 404 everywhere) and errors a person can act on."""

from __future__ import annotations

from pathlib import Path

import pytest
from svc_helpers import EXAMPLE, submit, upload_inputs, wait_for

from core.model import KinematicModel

pytestmark = [pytest.mark.service, pytest.mark.slow]


@pytest.fixture(scope="module")
def owner_job(redis_pg, clip):
    """Lab A's model, rig, video, batch and a succeeded job."""
    client = redis_pg.create_lab("owner")
    ids = upload_inputs(client, clip.video)
    job = wait_for(client, submit(client, ids, marker_diameter_px=4.0, chunk_size=40)["id"])
    assert job["status"] == "succeeded", job
    batch = client.post("/batches", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "trials": [{"video_ids": [ids["video_id"]]}],
                                          "options": {"chunk_size": 40}})
    assert batch.status_code == 202
    return client, {**ids, "job_id": job["id"], "batch_id": batch.json()["id"]}


def test_another_labs_key_gets_404_on_every_endpoint(redis_pg, owner_job):
    owner, ids = owner_job
    other = redis_pg.create_lab("other")
    m, r, v, j, b = ids["model_id"], ids["rig_id"], ids["video_id"], ids["job_id"], ids["batch_id"]
    gets = [f"/models/{m}", f"/models/{m}/model.xml", f"/models/{m}/histograms.xml", f"/rigs/{r}",
            f"/videos/{v}", f"/jobs/{j}", f"/jobs/{j}/angles.csv", f"/jobs/{j}/histograms.xml",
            f"/jobs/{j}/report.json", f"/jobs/{j}/archive.zip", f"/batches/{b}",
            f"/batches/{b}/archive.zip"]
    for path in gets:
        assert owner.get(path).status_code in (200, 409), path  # exists for its owner
        response = other.get(path)
        assert response.status_code == 404, path
        assert "not found" in response.json()["detail"]
    assert other.post(f"/jobs/{j}/cancel").status_code == 404
    job = {"model_id": m, "rig_id": r, "video_ids": [v]}
    assert other.post("/jobs", json=job).status_code == 404
    assert other.post("/batches", json={"model_id": m, "rig_id": r,
                                        "trials": [{"video_ids": [v]}]}).status_code == 404
    assert other.get("/jobs").json()["items"] == []
    assert owner.get(f"/jobs/{j}").json()["status"] == "succeeded"  # the cancel did nothing


def test_requests_without_a_valid_key_are_401(redis_pg):
    import httpx

    assert httpx.get(f"{redis_pg.url}/jobs").status_code == 401
    response = httpx.get(f"{redis_pg.url}/jobs", headers={"Authorization": "Bearer nope"})
    assert response.status_code == 401 and response.json()["detail"] == "unknown API key"


@pytest.mark.parametrize(("path", "body", "problem"), [
    ("/models", b"<model><joint name='a' parent='b'/></model>", "parent"),
    ("/models", b"<model", "XML"),
    ("/rigs", b'{"views": []}', "no views"),
    ("/rigs", b'{"views": [{"name": "a", "projection": {"type": "affine", "matrix": NaN}}]}', "NaN"),
])
def test_invalid_model_or_rig_is_422_naming_the_problem(redis_pg, path, body, problem):
    client = redis_pg.create_lab("invalid")
    response = client.post(path, content=body)
    assert response.status_code == 422
    assert problem.lower() in response.json()["detail"].lower(), response.json()


def _stored_videos(deployment) -> set[str]:
    folder = Path(deployment.env["MOCAP_DATA_DIR"]) / "storage" / "videos"
    return {p.name for p in folder.iterdir()} if folder.exists() else set()


def test_a_text_file_is_not_a_video_and_leaves_nothing_behind(redis_pg):
    client = redis_pg.create_lab("not-a-video")
    before = _stored_videos(redis_pg)
    response = client.post("/videos", files={"file": ("trial.avi", b"just text, not a video\n" * 100)})
    assert response.status_code == 422
    assert "video" in response.json()["detail"].lower() or "decod" in response.json()["detail"]
    assert _stored_videos(redis_pg) == before


@pytest.mark.parametrize(("options", "problem"), [
    ({"iterations": -5}, "iterations"),
    ({"chunk_size": 10**9}, "chunk_size"),
    ({"max_attempts": 0}, "max_attempts"),
    ({"no_such_option": 1}, "no_such_option"),
    ({"detector": {"threshold": "high"}}, "threshold"),
])
def test_absurd_options_are_422_naming_the_option(owner_job, options, problem):
    client, ids = owner_job
    response = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "video_ids": [ids["video_id"]], "options": options})
    assert response.status_code == 422
    assert problem in response.json()["detail"], response.json()


def test_wrong_number_of_videos_for_the_rig_is_422(owner_job):
    client, ids = owner_job
    response = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "video_ids": [ids["video_id"], ids["video_id"]]})
    assert response.status_code == 422
    assert "expects 1 video" in response.json()["detail"]


def test_results_before_success_are_409(owner_job, redis_pg):
    client, ids = owner_job
    job = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                     "video_ids": [ids["video_id"]]}).json()
    client.post(f"/jobs/{job['id']}/cancel")
    response = client.get(f"/jobs/{job['id']}/angles.csv")
    assert response.status_code == 409 and "canceled" in response.json()["detail"]


def test_model_can_also_be_sent_as_a_multipart_file(redis_pg):
    client = redis_pg.create_lab("multipart")
    response = client.post("/models", files={"file": ("m.xml", (EXAMPLE / "model.xml").read_bytes())})
    assert response.status_code == 201
    assert response.json()["dofs"] == KinematicModel.from_xml(EXAMPLE / "model.xml").dof_names
