"""Deleting models, rigs and videos (``DELETE /v1/models/{id}`` etc.): 204 for the owning lab,
404 for another, 409 naming the jobs while any job (finished or not) names the upload; the
row goes first, its files after, and files a crash left without a row are swept."""

from __future__ import annotations

import io
import os
import time
import zipfile
from pathlib import Path

import pytest
from sqlalchemy import text
from sqlalchemy.orm import Session
from svc_helpers import submit, upload_inputs

from service import crud
from service.storage import LocalStorage

pytestmark = [pytest.mark.service]

KINDS = ("models", "rigs", "videos")


@pytest.fixture(params=["embedded", "redis_pg"])
def deployment(request):
    """Each test on SQLite (embedded) and on PostgreSQL."""
    return request.getfixturevalue(request.param)


def _storage(deployment) -> Path:
    return Path(deployment.env["MOCAP_DATA_DIR"]) / "storage"


def _stored_keys(deployment, ids: dict[str, int]) -> list[str]:
    """Storage keys of the video and of the model's histogram archive."""
    with deployment.db().connect() as conn:
        video = conn.execute(text("SELECT storage_key FROM videos WHERE id = :v"), {"v": ids["video_id"]})
        versions = conn.execute(text("SELECT storage_key FROM histogram_versions WHERE model_id = :m"),
                                {"m": ids["model_id"]})
        return [*video.scalars(), *versions.scalars()]


def test_the_owner_deletes_unused_uploads_and_their_files(deployment, clip):
    client = deployment.create_lab("deleter")
    ids = upload_inputs(client, clip.video)
    keys = _stored_keys(deployment, ids)
    assert len(keys) == 2 and all((_storage(deployment) / k).is_file() for k in keys)
    other = deployment.create_lab("deleter-other")
    for kind in KINDS:
        path = f"/{kind}/{ids[f'{kind[:-1]}_id']}"
        refused = other.delete(path)
        assert refused.status_code == 404 and "not found" in refused.json()["detail"]
        assert client.get(path).status_code == 200  # another lab's DELETE did nothing
        deleted = client.delete(path)
        assert deleted.status_code == 204 and deleted.content == b""
        assert client.get(path).status_code == 404
        assert client.delete(path).status_code == 404
        assert client.get(f"/{kind}").json()["items"] == []
    assert not any((_storage(deployment) / k).exists() for k in keys)


def test_an_upload_a_job_names_is_409_naming_the_job_even_once_it_ended(deployment, clip):
    client = deployment.create_lab("in-use")
    ids = upload_inputs(client, clip.video)
    job = submit(client, ids, marker_diameter_px=4.0, chunk_size=40)
    assert client.post(f"/jobs/{job['id']}/cancel").json()["status"] == "canceled"
    for kind in KINDS:
        response = client.delete(f"/{kind}/{ids[f'{kind[:-1]}_id']}")
        assert response.status_code == 409, kind
        assert f"job(s) {job['id']}" in response.json()["detail"]
    assert all(client.get(f"/{kind}/{ids[f'{kind[:-1]}_id']}").status_code == 200 for kind in KINDS)
    assert all((_storage(deployment) / k).is_file() for k in _stored_keys(deployment, ids))


def test_a_succeeded_jobs_downloads_outlive_a_refused_delete(redis_pg, owner_job):
    """The owner's uploads are named by a succeeded job and a batch: 409 naming both, and the
    job's archive (model.xml and rig.json from those rows) still downloads."""
    client, ids = owner_job
    batch_job = client.get(f"/batches/{ids['batch_id']}").json()["jobs"][0]["id"]
    for kind in KINDS:
        response = client.delete(f"/{kind}/{ids[f'{kind[:-1]}_id']}")
        assert response.status_code == 409
        assert f"job(s) {ids['job_id']}, {batch_job};" in response.json()["detail"]
    archive = client.get(f"/jobs/{ids['job_id']}/archive.zip")
    assert archive.status_code == 200
    names = zipfile.ZipFile(io.BytesIO(archive.content)).namelist()
    assert {"angles.csv", "model.xml", "rig.json", "report.json"} <= set(names)


def test_files_a_crash_left_after_deleting_the_rows_are_swept(embedded, clip):
    """A crash between the committed DELETE and the file deletion (simulated: the rows deleted
    in SQL, the files kept and aged) leaves files no row names: the sweep the API runs on start
    removes them, and only them."""
    client = embedded.create_lab("crashed-delete")
    gone, kept = upload_inputs(client, clip.video), upload_inputs(client, clip.video)
    orphans, alive = _stored_keys(embedded, gone), _stored_keys(embedded, kept)
    with embedded.db().begin() as conn:
        conn.execute(text("DELETE FROM histogram_versions WHERE model_id = :m"), {"m": gone["model_id"]})
        conn.execute(text("DELETE FROM models WHERE id = :m"), {"m": gone["model_id"]})
        conn.execute(text("DELETE FROM videos WHERE id = :v"), {"v": gone["video_id"]})
    storage = LocalStorage(_storage(embedded))
    an_hour_ago = time.time() - 3601
    for key in orphans + alive:
        os.utime(storage.path(key), (an_hour_ago, an_hour_ago))
    with Session(embedded.db()) as session:
        assert crud.remove_orphans(session, storage, older_than_s=3600) == 2
    assert not any(storage.exists(k) for k in orphans)
    assert all(storage.exists(k) for k in alive)
