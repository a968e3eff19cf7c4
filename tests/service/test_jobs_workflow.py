"""Re-analysis, cancel, batches and listing through the real PostgreSQL + Redis deployment."""

from __future__ import annotations

import io
import itertools
import json
import time
import zipfile

import numpy as np
import pytest
from celery import Celery
from sqlalchemy import text
from svc_helpers import repeated, slow_rig, submit, upload_inputs, wait_for

from core.synth import write_video
from service.broker import FIT_CHUNK, PLAN_JOB, REANALYSE_IMAGE

pytestmark = [pytest.mark.service, pytest.mark.slow]


def test_images_over_the_threshold_are_requeued_and_every_attempt_recorded(redis_pg, clip):
    """A threshold no fit can meet: every image is re-analysed until it has its max_attempts
    or an attempt ends in its kept minimum (``settled``, ``core.fit.reanalyse_image``), each
    attempt a row."""
    client = redis_pg.create_lab("reanalysis")
    ids = upload_inputs(client, clip.video)
    job = wait_for(client, submit(client, ids, marker_diameter_px=4.0, error_threshold_px=1e-9,
                                  max_attempts=3, chunk_size=20)["id"])
    assert job["status"] == "succeeded", job
    assert job["progress"]["images_over_threshold"] == 40
    assert job["progress"]["reanalyses_pending"] == 0
    with redis_pg.db().connect() as conn:
        rows = conn.execute(text("SELECT sample, attempt, error_px FROM attempts WHERE job_id = :j "
                                 "ORDER BY sample, attempt"), {"j": job["id"]}).all()
        kept = conn.execute(text("SELECT sample, attempts, record FROM image_results WHERE job_id = :j"),
                            {"j": job["id"]}).all()
    best = {r.sample: r.attempts for r in kept}
    settled = {r.sample: (json.loads(r.record) if isinstance(r.record, str) else r.record)["settled"]
               for r in kept}
    assert [(r.sample, r.attempt) for r in rows] == [
        (s, a) for s in range(40) for a in range(1, best[s] + 1)]
    assert all(n == 3 or (n == 2 and settled[s]) for s, n in best.items())
    by_sample: dict[int, list[float]] = {}
    for r in rows:
        by_sample.setdefault(r.sample, []).append(r.error_px)
    # The best is kept: an image's recorded error never grows from one attempt to the next.
    assert all(a >= b for e in by_sample.values() for a, b in itertools.pairwise(e))
    report = client.get(f"/jobs/{job['id']}/report.json").json()
    assert report["reanalysed"] == 40 and report["service"]["attempts_total"] == len(rows)


def test_cancel_stops_a_running_job(redis_pg, clip, tmp_path):
    """A rig that cannot explain the markers makes every image slow (~40 ms, 400 images in two
    chunks: several seconds each); cancel stops a running chunk between images, and a chunk
    no worker has started yet (a busy machine) is canceled at once."""
    client = redis_pg.create_lab("cancel")
    ids = upload_inputs(client, repeated(clip.video, 10, tmp_path / "long.avi"), rig=slow_rig())
    job = submit(client, ids, chunk_size=200, max_attempts=1)
    wait_for(client, job["id"], {"running"}, timeout=60)
    t0 = time.monotonic()  # both chunks fitting (a fixed sleep lost this race on a loaded machine)
    while time.monotonic() - t0 < 60:
        with redis_pg.db().connect() as conn:
            running = conn.execute(text("SELECT count(*) FROM chunks WHERE job_id = :j "
                                        "AND status = 'running'"), {"j": job["id"]}).scalar_one()
        if running == 2:
            break
        time.sleep(0.05)
    canceled = client.post(f"/jobs/{job['id']}/cancel")
    assert canceled.status_code == 200 and canceled.json()["status"] == "canceled"
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30:
        with redis_pg.db().connect() as conn:
            chunks = conn.execute(text("SELECT status FROM chunks WHERE job_id = :j"),
                                  {"j": job["id"]}).scalars().all()
        if "running" not in chunks:
            break
        time.sleep(0.1)
    stopped_after = time.monotonic() - t0
    assert chunks == ["canceled", "canceled"], chunks  # stopped, not run to the end
    assert stopped_after < 3.0
    after = client.get(f"/jobs/{job['id']}").json()
    assert after["status"] == "canceled" and after["progress"]["images_done"] == 0
    assert client.get(f"/jobs/{job['id']}/angles.csv").status_code == 409


def test_batch_one_job_per_trial_and_archive_with_a_folder_each(redis_pg, clip):
    client = redis_pg.create_lab("batch")
    ids = upload_inputs(client, clip.video)
    with clip.video.open("rb") as f:
        second = client.post("/videos", files={"file": ("trial2.avi", f)}).json()["id"]
    response = client.post("/batches", json={
        "model_id": ids["model_id"], "rig_id": ids["rig_id"],
        "trials": [{"video_ids": [ids["video_id"]]}, {"video_ids": [second]}],
        "options": {"marker_diameter_px": 4.0, "chunk_size": 20}})
    assert response.status_code == 202, response.text
    batch = response.json()
    assert response.headers["Location"] == f"/v1/batches/{batch['id']}"
    assert [j["trial"] for j in batch["jobs"]] == [0, 1]
    t0 = time.monotonic()
    while (state := client.get(f"/batches/{batch['id']}").json())["status"] == "running":
        assert time.monotonic() - t0 < 120, state
        time.sleep(0.3)
    assert state["status"] == "succeeded" and state["statuses"] == {"succeeded": 2}
    assert state["progress"]["images_done"] == 80
    names = zipfile.ZipFile(io.BytesIO(client.get(f"/batches/{batch['id']}/archive.zip").content)).namelist()
    folders = sorted({n.split("/")[0] for n in names})
    assert folders == [f"trial-000-job-{batch['jobs'][0]['id']}", f"trial-001-job-{batch['jobs'][1]['id']}"]
    assert len(names) == 18  # 9 files a trial: results, exports (core.export), model and rig

    # Listing: newest first, by status, one page at a time.
    page = client.get("/jobs", params={"status": "succeeded", "limit": 1}).json()
    assert [j["id"] for j in page["items"]] == [batch["jobs"][1]["id"]]
    rest = client.get("/jobs", params={"status": "succeeded", "limit": 1, "cursor": page["next_cursor"]})
    assert [j["id"] for j in rest.json()["items"]] == [batch["jobs"][0]["id"]]
    assert rest.json()["next_cursor"] is None
    assert client.get("/jobs", params={"status": "failed"}).json()["items"] == []


def test_footage_that_does_not_fit_the_rig_is_refused_at_submission(redis_pg, tmp_path):
    """Footage smaller than the rig's regions of interest: the job is refused (422) with
    ``core.rig.Rig.check_videos``' message from the probed sizes of the videos, naming the
    upload, before any job exists (it used to fail in planning, after a worker had probed the
    videos again)."""
    client = redis_pg.create_lab("failing")
    small = tmp_path / "small.avi"
    write_video(small, (np.zeros((100, 100), np.uint8) for _ in range(12)), fps=50.0)
    ids = upload_inputs(client, small)
    response = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "video_ids": [ids["video_id"]]})
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert detail == (f"view 'side': roi [0, 0, 360, 288] lies outside the 100×100 frame of the rig's "
                      f"video 0, video {ids['video_id']} ('small.avi')")
    assert client.get("/jobs").json()["items"] == []


def test_messages_delivered_again_change_nothing(redis_pg, clip):
    """Every task of a finished job sent again (as a lost acknowledgement would): no new rows,
    no new archive version, the job unchanged."""
    client = redis_pg.create_lab("redelivery")
    ids = upload_inputs(client, clip.video)
    job = wait_for(client, submit(client, ids, marker_diameter_px=4.0, chunk_size=20)["id"])
    assert job["status"] == "succeeded"
    queries = {
        "images": "SELECT count(*) FROM image_results WHERE job_id = :j",
        "attempts": "SELECT count(*) FROM attempts WHERE job_id = :j",
        "chunks": "SELECT count(*) FROM chunks WHERE job_id = :j",
        "versions": "SELECT count(*) FROM histogram_versions WHERE job_id = :j",
    }

    def counts() -> dict[str, int]:
        with redis_pg.db().connect() as conn:
            return {k: conn.execute(text(q), {"j": job["id"]}).scalar_one() for k, q in queries.items()}

    before = counts()
    assert before["images"] == 40 and before["chunks"] == 2 and before["versions"] == 1
    assert before["attempts"] >= 40  # one per image, more for those re-analysed
    with redis_pg.db().connect() as conn:
        chunk_ids = conn.execute(text("SELECT id FROM chunks WHERE job_id = :j"), {"j": job["id"]}).scalars()
        chunk_ids = list(chunk_ids)
    broker = Celery(broker=redis_pg.env["MOCAP_BROKER_URL"])
    queue = redis_pg.env["MOCAP_QUEUE"]
    broker.send_task(PLAN_JOB, args=[job["id"]], queue=queue)
    for chunk_id in chunk_ids:
        broker.send_task(FIT_CHUNK, args=[chunk_id], queue=queue)
    broker.send_task(REANALYSE_IMAGE, args=[job["id"], 0, 2], queue=queue)
    # A job submitted after them succeeds only once the worker has taken them all (FIFO queue).
    later = wait_for(client, submit(client, ids, chunk_size=40)["id"])
    assert later["status"] == "succeeded"
    after = counts()
    assert after == before
    assert client.get(f"/jobs/{job['id']}").json() == job
