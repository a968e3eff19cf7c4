"""Videos at the limits (issue 12, items 4, 7 and 8), on PostgreSQL through the HTTP API.

- an upload of exactly MOCAP_MAX_UPLOAD_BYTES is stored, one byte more is 413, and the
  size column holds sizes past 2**31 (it was 32-bit: a 2 GiB upload was a 500 and an orphan);
- a stored video without a row is deleted when the API starts;
- videos that cannot be fitted together are 422 at submission, naming them by id and name;
- a job that fails on its video names the video as uploaded, and the worker logs the lab's
  error as expected, without a traceback.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import cv2
import httpx
import pytest
from conftest import Deployment, free_port, redis_pg_deployment, wait_healthy
from sqlalchemy import text
from sqlalchemy.orm import Session
from svc_helpers import upload_inputs, wait_for

from core.synth import write_video
from service import crud
from service.labs import create_lab
from service.settings import Settings
from service.storage import LocalStorage

pytestmark = [pytest.mark.service, pytest.mark.slow]


def lab_client(deployment: Deployment, name: str) -> httpx.Client:
    """A new lab's client, the lab written straight into the database (``mocap admin create-lab``
    is tested in test_admin_cli.py; a process per lab would cost seconds)."""
    with Session(deployment.db()) as session:
        _, key = create_lab(session, name)
        session.commit()
    return httpx.Client(base_url=deployment.url, headers={"Authorization": f"Bearer {key}"}, timeout=30)


def _frames(video: Path, count: int) -> list:
    capture, frames = cv2.VideoCapture(str(video)), []
    while len(frames) < count and (frame := capture.read())[0]:
        frames.append(cv2.cvtColor(frame[1], cv2.COLOR_BGR2GRAY))
    capture.release()
    return frames


def _variant(clip, folder: Path, name: str, count: int, fps: float) -> Path:
    """The first ``count`` frames of the clip, written at ``fps``."""
    path = folder / name
    write_video(path, _frames(clip.video, count), fps=fps)
    return path


@pytest.fixture(scope="module")
def exact(tmp_path_factory, clip):
    """An API (no workers) whose upload limit is exactly the clip's size."""
    with redis_pg_deployment(tmp_path_factory.mktemp("exact"), "exact", workers=0,
                             max_upload_bytes=str(clip.video.stat().st_size)) as deployment:
        yield deployment


@pytest.fixture(scope="module")
def client(exact) -> httpx.Client:
    return lab_client(exact, "exact")


@pytest.fixture(scope="module")
def pair(client, clip) -> dict[str, int]:
    """A model, a rig of two cameras and the clip as the first camera's video."""
    ids = upload_inputs(client, clip.video)
    a = client.post("/videos", files={"file": ("a.avi", clip.video.read_bytes())}).json()["id"]
    return {"model_id": ids["model_id"], "rig_id": _two_view_rig(client), "a": a}


def _storage(deployment: Deployment) -> Path:
    return Path(deployment.env["MOCAP_DATA_DIR"]) / "storage"


def test_an_upload_of_exactly_the_limit_is_stored_and_one_byte_more_is_413(exact, client, clip):
    before = set((_storage(exact) / "videos").glob("*"))
    data = clip.video.read_bytes()
    stored = client.post("/videos", files={"file": ("clip.avi", data)})
    assert stored.status_code == 201, stored.text
    assert stored.json()["size_bytes"] == len(data)
    refused = client.post("/videos", files={"file": ("clip.avi", data + b"\0")})
    assert refused.status_code == 413
    added = set((_storage(exact) / "videos").glob("*")) - before
    assert len(added) == 1  # the refused upload left nothing


def test_the_size_column_holds_sizes_past_2_31_on_postgresql(exact, clip):
    """Through the crud layer (a 2 GiB upload would take minutes): 2**31 + 1 bytes round-trips."""
    storage = LocalStorage(_storage(exact))
    key = f"videos/{uuid.uuid4().hex}"
    storage.put(key, [clip.video.read_bytes()])
    settings = Settings(database_url=exact.database_url, data_dir=exact.env["MOCAP_DATA_DIR"])
    with Session(exact.db()) as session:
        lab, _ = create_lab(session, "big")
        video_id = crud.register_video(session, storage, lab, settings, key=key, filename="big.avi",
                                       size=2**31 + 1, sha256="0" * 64).id
    with exact.db().connect() as conn:
        size = conn.execute(text("SELECT size_bytes FROM videos WHERE id = :v"), {"v": video_id}).scalar_one()
    assert size == 2**31 + 1


def test_stored_videos_without_a_row_are_deleted_when_the_api_starts(exact, client, clip, tmp_path):
    """An old orphan (its API died between storing and registering) goes; a recent one may be
    being registered and stays, as do registered videos."""
    registered = client.post("/videos", files={"file": ("clip.avi", clip.video.read_bytes())}).json()
    videos = _storage(exact) / "videos"
    old, recent = videos / uuid.uuid4().hex, videos / uuid.uuid4().hex
    old.write_bytes(b"x" * 1000)
    recent.write_bytes(b"y" * 1000)
    two_hours_ago = time.time() - 7200
    os.utime(old, (two_hours_ago, two_hours_ago))
    before = set(videos.iterdir())
    port = free_port()
    second = Deployment("second", f"http://127.0.0.1:{port}/v1", exact.env, exact.database_url)
    second.processes.append(subprocess.Popen(
        [sys.executable, "-m", "service.api.server", "--port", str(port), "--log-level", "warning"],
        env=exact.env, stdout=(tmp_path / "api.log").open("w"), stderr=subprocess.STDOUT))
    try:
        wait_healthy(second)
    finally:
        second.stop()
    assert set(videos.iterdir()) == before - {old}
    assert client.get(f"/videos/{registered['id']}").json()["sha256"] == registered["sha256"]


def _two_view_rig(client: httpx.Client) -> int:
    """The example rig with its top view on a second camera."""
    rig = {"views": [
        {"name": "side", "video": 0, "roi": [0, 0, 360, 288],
         "projection": {"type": "affine", "matrix": [[3.0, 0, 0, 240], [0, -3.0, 0, 184]]}},
        {"name": "top", "video": 1, "roi": [0, 288, 360, 288],
         "projection": {"type": "affine", "matrix": [[3.0, 0, 0, 240], [0, 0, 3.0, 438]]}}]}
    response = client.post("/rigs", json=rig)
    assert response.status_code == 201, response.text
    return response.json()["id"]


@pytest.mark.parametrize(("second", "problem"), [
    ((30, 50.0), "same number of frames (within 2); got video {a} ('a.avi'): 40, video {b} ('b.avi'): 30"),
    ((40, 25.0), "same frame rate; video {a} ('a.avi') has 50 fps, video {b} ('b.avi') 25"),
])
def test_videos_that_cannot_be_fitted_together_are_422_at_submission(client, pair, clip, tmp_path, second,
                                                                    problem):
    ids, rig_id, a = pair, pair["rig_id"], pair["a"]
    jobs_before = client.get("/jobs").json()["items"]
    b_path = _variant(clip, tmp_path, "b.avi", *second)
    b = client.post("/videos", files={"file": ("b.avi", b_path.read_bytes())}).json()["id"]
    response = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": rig_id, "video_ids": [a, b]})
    assert response.status_code == 422
    assert problem.format(a=a, b=b) in response.json()["detail"]
    assert client.get("/jobs").json()["items"] == jobs_before
    # Within the tolerance `mocap fit` allows (2 frames), the job is taken.
    c_path = _variant(clip, tmp_path, "c.avi", 38, 50.0)
    c = client.post("/videos", files={"file": ("c.avi", c_path.read_bytes())}).json()["id"]
    taken = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": rig_id, "video_ids": [a, c]})
    assert taken.status_code == 202, taken.text


@pytest.mark.slow
def test_a_truncated_video_shows_its_missing_frames_in_the_job_report(redis_pg, clip):
    client = lab_client(redis_pg, "truncated")
    data = clip.video.read_bytes()
    cut = Path(redis_pg.env["MOCAP_DATA_DIR"]) / "cut.avi"
    cut.write_bytes(data[: len(data) * 3 // 4])
    ids = upload_inputs(client, cut)
    video = client.get(f"/videos/{ids['video_id']}").json()
    assert video["announced_frames"] == 40 and video["frames"] < 40 and "missing" in video["warning"]
    job = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                     "video_ids": [ids["video_id"]], "options": {"marker_diameter_px": 4}})
    assert wait_for(client, job.json()["id"])["status"] == "succeeded"
    report = client.get(f"/jobs/{job.json()['id']}/report.json").json()
    assert report["images"] == video["frames"]
    assert report["videos"] == [{"id": video["id"], "filename": "cut.avi", "name": None, "metadata": None,
                                 "frames": video["frames"], "announced_frames": 40,
                                 "warning": video["warning"]}]


def test_a_job_failing_on_its_video_names_it_as_uploaded_and_logs_no_traceback(redis_pg, clip):
    """The stored file is damaged after upload (a disk fault, or a file replaced by hand): the
    worker's probe fails. The job's error names the video by id and upload name; the worker
    logs the lab's error as expected (one line), not as "raised unexpected" with a traceback."""
    client = lab_client(redis_pg, "damaged")
    ids = upload_inputs(client, clip.video)
    with redis_pg.db().connect() as conn:
        key = conn.execute(text("SELECT storage_key FROM videos WHERE id = :v"),
                           {"v": ids["video_id"]}).scalar_one()
    (Path(redis_pg.env["MOCAP_DATA_DIR"]) / "storage" / key).write_bytes(b"not a video any more\n" * 50)
    job = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                     "video_ids": [ids["video_id"]]}).json()
    failed = wait_for(client, job["id"])
    assert failed["status"] == "failed"
    assert failed["error"] == (f"VideoError: video {ids['video_id']} ('{clip.video.name}'): not a video "
                               "file FFmpeg can decode (or it is damaged)")
    time.sleep(0.5)  # the worker logs the task's end after recording the failure
    log = [line for line in (redis_pg.data / "worker.log").read_text().splitlines()
           if Path(key).name in line]
    assert any("raised expected" in line for line in log), log
    assert not any("unexpected" in line or "Traceback" in line for line in log), log

