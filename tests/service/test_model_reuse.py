"""Uploading a model the lab already has (same XML bytes) names that model and its histogram
archive, or with ``?reuse=true`` answers with it instead of starting a new archive; another
lab's identical model is never revealed."""

from __future__ import annotations

import hashlib

import pytest

from core.examples import LOCUST

pytestmark = [pytest.mark.service]

XML = (LOCUST / "model.xml").read_bytes()


@pytest.fixture(params=["embedded", "redis_pg"])
def deployment(request):
    """Each test on SQLite (embedded) and on PostgreSQL."""
    return request.getfixturevalue(request.param)


def _upload(client, **params):
    return client.post("/models", content=XML, params=params, headers={"Content-Type": "application/xml"})


def test_an_identical_model_is_offered_and_reused_only_within_the_lab(deployment):
    lab = deployment.create_lab("reuser")
    first = _upload(lab)
    assert first.status_code == 201
    assert first.json()["sha256"] == hashlib.sha256(XML).hexdigest()
    assert (first.json()["existing_model_id"], first.json()["existing"], first.json()["reused"]) == \
        (None, None, False)
    second = _upload(lab)
    assert second.status_code == 201 and second.json()["id"] != first.json()["id"]
    assert second.json()["existing_model_id"] == first.json()["id"]
    assert second.json()["existing"] == {"model_id": first.json()["id"], "histogram_versions": 1,
                                         "latest_version": 1}
    reused = _upload(lab, reuse="true")
    assert reused.status_code == 200  # the oldest of two archives with one version each
    assert (reused.json()["id"], reused.json()["reused"]) == (first.json()["id"], True)
    assert len(lab.get("/models").json()["items"]) == 2  # nothing stored

    other = deployment.create_lab("reuser-other")
    theirs = _upload(other)
    assert theirs.status_code == 201
    assert (theirs.json()["existing_model_id"], theirs.json()["existing"]) == (None, None)
    not_shared = _upload(other, reuse="true")
    assert not_shared.status_code == 200 and not_shared.json()["id"] == theirs.json()["id"]


def test_the_archive_with_the_most_versions_is_offered(redis_pg, owner_job):
    """The owner's model has folded a succeeded job (version 2 or later): an identical upload
    names it, and ``?reuse=true`` gives it back, so jobs go on with that archive."""
    client, ids = owner_job
    versions = client.get(f"/models/{ids['model_id']}").json()["histogram_versions"]
    assert versions >= 2
    offered = _upload(client)
    assert offered.status_code == 201
    assert offered.json()["existing_model_id"] == ids["model_id"]
    assert offered.json()["existing"]["latest_version"] >= versions
    reused = _upload(client, reuse="true")
    assert (reused.status_code, reused.json()["id"]) == (200, ids["model_id"])
    assert reused.json()["histogram_versions"] >= versions


def test_a_model_uploaded_with_a_name_and_metadata_keeps_them(deployment):
    lab = deployment.create_lab("named-model")
    response = _upload(lab, name="locust A", metadata='{"animal": "locust", "leg": "hind"}')
    assert response.status_code == 201, response.text
    model = lab.get(f"/models/{response.json()['id']}").json()
    assert (model["name"], model["metadata"]) == ("locust A", {"animal": "locust", "leg": "hind"})
