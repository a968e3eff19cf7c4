"""Tenancy (another lab's ids are 404 everywhere) and errors a person can act on."""

from __future__ import annotations

import json
import subprocess
import sys

import httpx
import pytest
from conftest import Deployment, free_port, wait_healthy
from svc_helpers import upload_inputs

from core.examples import LOCUST
from core.model import KinematicModel

pytestmark = [pytest.mark.service, pytest.mark.slow]


def _paths_with_ids(deployment) -> list[tuple[str, str]]:
    """(method, path template) of every operation that takes an id, read from the OpenAPI schema,
    so an endpoint added later is covered without editing this test."""
    schema = httpx.get(deployment.url.removesuffix("/v1") + "/openapi.json").json()
    return [(method.upper(), path.removeprefix("/v1")) for path, item in schema["paths"].items()
            for method in item if "{" in path]


def test_another_labs_key_gets_404_on_every_endpoint(redis_pg, owner_job, clip):
    owner, ids = owner_job
    other = redis_pg.create_lab("other")
    values = {"model_id": ids["model_id"], "rig_id": ids["rig_id"], "video_id": ids["video_id"],
              "job_id": ids["job_id"], "batch_id": ids["batch_id"], "name": "plots/angles.svg"}
    operations = _paths_with_ids(redis_pg)
    assert len(operations) == 19, operations  # 14 downloads and reads, cancel, detect-preview, 3 deletes
    for method, template in operations:
        path = template.format(**values)
        if method == "GET":
            assert owner.get(path).status_code in (200, 409), path  # exists for its owner
        elif path.endswith("/detect-preview"):
            assert owner.post(path).status_code == 422, path  # its owner is asked for a body
        response = other.request(method, path)
        assert response.status_code == 404, (method, path)
        assert "not found" in response.json()["detail"]
    # Submissions naming one foreign id among the other lab's own: each is 404.
    own = upload_inputs(other, clip.video)
    for name, foreign in (("model_id", ids["model_id"]), ("rig_id", ids["rig_id"]),
                          ("video_id", ids["video_id"])):
        mixed = {**own, name: foreign}
        job = {"model_id": mixed["model_id"], "rig_id": mixed["rig_id"], "video_ids": [mixed["video_id"]]}
        assert other.post("/jobs", json=job).status_code == 404, name
        batch = {"model_id": mixed["model_id"], "rig_id": mixed["rig_id"],
                 "trials": [{"video_ids": [own["video_id"]]}, {"video_ids": [mixed["video_id"]]}]}
        assert other.post("/batches", json=batch).status_code == 404, name
    assert other.get("/jobs").json()["items"] == []  # nothing half-created
    assert [j["id"] for j in owner.get("/jobs").json()["items"]][-1] == ids["job_id"]
    assert owner.get(f"/jobs/{ids['job_id']}").json()["status"] == "succeeded"  # the cancel did nothing


def test_requests_without_a_valid_key_are_401(redis_pg):
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


@pytest.mark.parametrize(("options", "problem"), [
    ({"iterations": -5}, "iterations"),
    ({"chunk_size": 10**9}, "chunk_size"),
    ({"max_attempts": 0}, "max_attempts"),
    ({"no_such_option": 1}, "no_such_option"),
    ({"detector": {"threshold": "high"}}, "threshold"),
    ({"error_threshold_px": float("nan")}, "error_threshold_px"),
    ({"detector": {"threshold": float("nan")}}, "detector.threshold"),
    ({"marker_diameter_px": float("inf")}, "marker_diameter_px"),
    ({"seed": -1}, "seed"),
    ({"prior_weight": 0}, "prior_weight"),
    ({"root_start": [[240, 184], [240, 438]]}, "root_start needs root_marker"),
    ({"root_marker": "M0", "root_start": [[240, 184]]}, "root_start has 1 (u, v) pair(s) for a rig of 2"),
    ({"root_marker": "M9"}, "root marker 'M9' is not a marker"),
    ({"root_marker": "M0", "root_max_jump_px": 0}, "root_max_jump_px"),
])
def test_absurd_options_are_422_naming_the_option(owner_job, options, problem):
    """NaN and Infinity are sent as the JSON tokens Python's json module writes and reads."""
    client, ids = owner_job
    body = {"model_id": ids["model_id"], "rig_id": ids["rig_id"], "video_ids": [ids["video_id"]],
            "options": options}
    response = client.post("/jobs", content=json.dumps(body), headers={"Content-Type": "application/json"})
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
    response = client.post("/models", files={"file": ("m.xml", (LOCUST / "model.xml").read_bytes())})
    assert response.status_code == 201
    assert response.json()["dofs"] == KinematicModel.from_xml(LOCUST / "model.xml").dof_names


@pytest.fixture
def api_without_broker(redis_pg, tmp_path):
    """A second API process on the same database whose broker is unreachable (a closed port)."""
    env = {**redis_pg.env, "MOCAP_BROKER_URL": "redis://127.0.0.1:1/0"}
    port = free_port()
    deployment = Deployment("no-broker", f"http://127.0.0.1:{port}/v1", env, redis_pg.database_url)
    deployment.processes.append(subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "service.api.app:create_app", "--factory", "--port", str(port),
         "--log-level", "warning"], env=env, stdout=(tmp_path / "api.log").open("w"),
        stderr=subprocess.STDOUT))
    try:
        wait_healthy(deployment)
        yield deployment
    finally:
        deployment.stop()


def test_a_job_the_broker_cannot_take_is_503_and_failed_not_left_queued(api_without_broker, clip):
    client = api_without_broker.create_lab("no-broker")
    ids = upload_inputs(client, clip.video)
    response = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "video_ids": [ids["video_id"]]})
    assert response.status_code == 503
    assert "unreachable" in response.json()["detail"]
    jobs = client.get("/jobs").json()["items"]
    assert [j["status"] for j in jobs] == ["failed"]
    assert "submit it again" in jobs[0]["error"]
