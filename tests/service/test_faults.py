"""Faults against real PostgreSQL, Redis, uvicorn and Celery worker processes (issue 5).

Each test starts the workers it needs (``faults`` runs only the API), does to them what
happens in production (SIGKILL, SIGTERM, FLUSHDB, a crashing chunk, a duplicate message,
an API killed mid-upload) and checks the database afterwards: every image exactly once.
The figures logged (``--log-cli-level=INFO``) are the ones in docs/RELIABILITY.md.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest
import redis
from celery import Celery
from conftest import REDIS_FAULTS_URL, Deployment
from sqlalchemy import text
from svc_helpers import repeated, slow_rig, submit, upload_inputs, wait_for

from service.broker import FIT_CHUNK

pytestmark = [pytest.mark.service, pytest.mark.slow]
logger = logging.getLogger(__name__)

SLOW_IMAGES = 120  # the clip 3 times over, ~40 ms an image with the slow rig


@contextmanager
def worker(faults: Deployment, concurrency: int = 2, **env: str) -> Iterator[subprocess.Popen]:
    """A ``mocap worker`` for the test's duration, killed (whole group) if still running."""
    process = faults.start_worker(concurrency, **env)
    try:
        yield process
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@pytest.fixture(scope="module")
def slow_ids(faults, clip, tmp_path_factory) -> dict[str, Any]:
    """Inputs whose chunks take seconds: the slow rig on the clip three times over."""
    client = faults.create_lab("slow")
    video = repeated(clip.video, 3, tmp_path_factory.mktemp("slow") / "long.avi")
    return upload_inputs(client, video, rig=slow_rig()) | {"key": client.headers["Authorization"]}


def _client(faults: Deployment, ids: dict[str, Any]) -> httpx.Client:
    return httpx.Client(base_url=faults.url, headers={"Authorization": str(ids["key"])}, timeout=30)


def _rows(faults: Deployment, sql: str, j: int | str) -> list[Any]:
    with faults.db().connect() as conn:
        return list(conn.execute(text(sql), {"j": j}).all())


def _wait_chunks(faults: Deployment, job_id: int, status: str, count: int, timeout: float = 60) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        rows = _rows(faults, "SELECT status FROM chunks WHERE job_id = :j", job_id)
        if sum(r.status == status for r in rows) >= count:
            return
        time.sleep(0.05)
    raise AssertionError(f"job {job_id}: fewer than {count} chunks {status} after {timeout} s")


def _assert_every_image_once(faults: Deployment, job_id: int, images: int) -> None:
    """One result row and one first-attempt row per image: none duplicated, none missing."""
    samples = [r.sample for r in _rows(faults, "SELECT sample FROM image_results WHERE job_id = :j "
                                               "ORDER BY sample", job_id)]
    assert samples == list(range(images))
    firsts = _rows(faults, "SELECT sample FROM attempts WHERE job_id = :j AND attempt = 1", job_id)
    assert sorted(r.sample for r in firsts) == list(range(images))


def _reaped(faults: Deployment, since: int) -> str:
    """The reaper's reports in the workers' log after byte ``since``."""
    assert faults.data is not None
    with (faults.data / "worker.log").open("rb") as log:
        log.seek(since)
        return "".join(line for line in log.read().decode(errors="replace").splitlines(keepends=True)
                       if "reaper sent again" in line)


def _log_size(faults: Deployment) -> int:
    assert faults.data is not None
    log = faults.data / "worker.log"
    return log.stat().st_size if log.exists() else 0


def _attempts(faults: Deployment, job_id: int) -> list[int]:
    return [r.attempts for r in _rows(faults, "SELECT attempts FROM chunks WHERE job_id = :j "
                                               "ORDER BY index", job_id)]


def test_sigkill_mid_chunk_the_reaper_runs_it_again(faults, slow_ids):
    """Both chunks fitting, the whole worker (main process and pool) killed: the messages are
    stuck unacknowledged in Redis for the visibility timeout (an hour), so only the reaper
    brings them back. Two ``mocap reap`` at once re-queue each chunk once: two messages queued."""
    client = _client(faults, slow_ids)
    with worker(faults) as first:
        job = submit(client, slow_ids, chunk_size=60, max_attempts=1)["id"]
        _wait_chunks(faults, job, "running", 2)
        time.sleep(0.5)
        os.killpg(first.pid, signal.SIGKILL)
        killed = time.monotonic()
        first.wait()
    time.sleep(2.5)  # heartbeats now older than MOCAP_HEARTBEAT_TIMEOUT_S=2
    reapers = [subprocess.Popen([sys.executable, "-m", "service.cli", "reap"], env=faults.env,
                                stdout=subprocess.PIPE, text=True) for _ in range(2)]
    outputs = [r.communicate(timeout=60)[0] for r in reapers]
    stale = [int(out.split("stale chunks ")[1].split(",")[0]) for out in outputs]
    assert sum(stale) == 2, outputs  # split between the two or all in one: never a chunk twice
    assert redis.Redis.from_url(REDIS_FAULTS_URL).llen(faults.env["MOCAP_QUEUE"]) == 2
    with worker(faults):
        done = wait_for(client, job, timeout=90)
    recovered = time.monotonic() - killed
    assert done["status"] == "succeeded", done
    assert _attempts(faults, job) == [2, 2]
    _assert_every_image_once(faults, job, SLOW_IMAGES)
    logger.info("SIGKILL: recovered in %.1f s, 2 chunks re-queued, %d images checked", recovered, SLOW_IMAGES)


def test_redis_flushed_mid_job_the_reaper_sends_again_from_the_database(faults, slow_ids, clip):
    """One worker slot. Flushed with one chunk fitting and three waiting in Redis; then, on
    another job, with the re-analyses of its 40 images queued: both sent again from the
    database, each image fitted and re-analysed once."""
    client = _client(faults, slow_ids)
    flush = redis.Redis.from_url(REDIS_FAULTS_URL).flushdb
    fast = upload_inputs(client, clip.video)
    with worker(faults, concurrency=1):
        job = submit(client, slow_ids, chunk_size=30, max_attempts=1)["id"]
        _wait_chunks(faults, job, "running", 1)
        waiting = {r.id for r in _rows(faults, "SELECT id FROM chunks WHERE job_id = :j "
                                                "AND status = 'queued'", job)}
        since = _log_size(faults)
        flush()
        flushed = time.monotonic()
        done = wait_for(client, job, timeout=90)
        lost = re.findall(r"lost_chunks=\[([\d, ]*)\]", _reaped(faults, since))
        chunks_recovered = time.monotonic() - flushed
        again = submit(client, fast, marker_diameter_px=4.0, error_threshold_px=1e-9, max_attempts=2,
                       chunk_size=40)["id"]
        wait_for(client, again, {"reanalysing"}, timeout=60)
        since = _log_size(faults)
        flush()
        flushed = time.monotonic()
        redone = wait_for(client, again, timeout=90)
        recovered = time.monotonic() - flushed
    assert len(waiting) == 3
    assert {int(i) for ids in lost for i in ids.split(",") if i.strip()} == waiting
    assert done["status"] == redone["status"] == "succeeded", (done, redone)
    assert _attempts(faults, job) == [1, 1, 1, 1]  # sent again, fitted once
    _assert_every_image_once(faults, job, SLOW_IMAGES)
    _assert_every_image_once(faults, again, 40)
    attempts = _rows(faults, "SELECT sample, attempt FROM attempts WHERE job_id = :j ORDER BY 1, 2", again)
    assert [tuple(r) for r in attempts] == [(s, a) for s in range(40) for a in (1, 2)]
    resent = [int(n) for n in re.findall(r"lost_reanalyses=(\d+)", _reaped(faults, since))]
    assert sum(resent) > 0  # the reaper, not a surviving message, finished the job
    logger.info("FLUSHDB: job done %.1f s after a flush mid-chunks (%d chunks sent again), another "
                "%.1f s after a flush mid-re-analysis; %d images, %d attempts checked",
                chunks_recovered, len(waiting), recovered, SLOW_IMAGES + 40, len(attempts))
    logger.info("FLUSHDB: %d re-analyses sent again", sum(resent))


def test_a_chunk_that_kills_its_worker_fails_its_job_after_bounded_attempts(faults, clip):
    """MOCAP_CRASH_CHUNK makes the worker process exit at chunk 1 of one job, every time;
    Celery hands the message back each time, and the 4th delivery gives up. A job
    submitted alongside succeeds."""
    client = faults.create_lab("poison")
    ids = upload_inputs(client, clip.video)
    poison = submit(client, ids, marker_diameter_px=4.0, chunk_size=20)["id"]
    healthy = submit(client, ids, marker_diameter_px=4.0, chunk_size=20)["id"]
    t0 = time.monotonic()
    with worker(faults, MOCAP_CRASH_CHUNK=f"{poison}:1"):
        failed = wait_for(client, poison, timeout=90)
        succeeded = wait_for(client, healthy, timeout=90)
    assert failed["status"] == "failed", failed
    assert failed["error"].startswith("chunk 1 (images 20-39) was started 3 times and never finished")
    assert "MOCAP_MAX_CHUNK_ATTEMPTS=3" in failed["error"]
    chunks = _rows(faults, "SELECT index, status, attempts FROM chunks WHERE job_id = :j ORDER BY index",
                   poison)
    assert [(c.status, c.attempts) for c in chunks] == [("done", 1), ("failed", 3)]
    assert succeeded["status"] == "succeeded", succeeded
    _assert_every_image_once(faults, healthy, 40)
    logger.info("poison chunk: job failed after 3 attempts in %.1f s; the other job succeeded "
                "with 40 images", time.monotonic() - t0)


def test_a_worker_dying_between_the_last_chunk_and_the_merge_is_resumed(faults, clip):
    """``JOB:1:done``: the worker process exits once the last chunk is counted done, before the
    merge. The message handed back finds the chunk done; the reaper sees every chunk done and
    nothing moving, and sends ``resume_job``."""
    client = faults.create_lab("resume")
    ids = upload_inputs(client, clip.video)
    job = submit(client, ids, marker_diameter_px=4.0, chunk_size=20)["id"]
    since, t0 = _log_size(faults), time.monotonic()
    with worker(faults, concurrency=1, MOCAP_CRASH_CHUNK=f"{job}:1:done"):  # chunks in order
        done = wait_for(client, job, timeout=90)
    took = time.monotonic() - t0
    assert done["status"] == "succeeded", done
    assert done["progress"]["chunks_done"] == 2 and done["progress"]["images_done"] == 40
    assert f"resumed=[{job}]" in _reaped(faults, since)
    assert _attempts(faults, job) == [1, 1]
    _assert_every_image_once(faults, job, 40)
    logger.info("worker died before the merge: resumed by the reaper, job done %.1f s after the "
                "worker started", took)


def test_two_workers_fitting_the_same_chunk_give_the_single_delivery_result(faults, slow_ids):
    """Each chunk's message sent a second time while the first delivery fits it: two worker
    processes fit the same chunk at once. Results equal those of a job delivered once
    (same inputs, options and starting histograms)."""
    client = _client(faults, slow_ids)
    options = {"chunk_size": 60, "max_attempts": 1, "histogram_version": 1}
    broker = Celery(broker=faults.env["MOCAP_BROKER_URL"])
    with worker(faults), worker(faults):
        single = wait_for(client, submit(client, slow_ids, **options)["id"], timeout=90)
        twice = submit(client, slow_ids, **options)["id"]
        _wait_chunks(faults, twice, "running", 2)
        for (chunk_id,) in _rows(faults, "SELECT id FROM chunks WHERE job_id = :j", twice):
            broker.send_task(FIT_CHUNK, args=[chunk_id], queue=faults.env["MOCAP_QUEUE"])
        doubled = wait_for(client, twice, timeout=90)
    assert single["status"] == doubled["status"] == "succeeded"
    assert _attempts(faults, twice) == [2, 2]  # both deliveries started both chunks
    _assert_every_image_once(faults, twice, SLOW_IMAGES)
    for name in ("angles.csv", "histograms.xml"):
        assert (client.get(f"/jobs/{twice}/{name}").content
                == client.get(f"/jobs/{single['id']}/{name}").content), name
    same = "SELECT sample, attempt, error_px, objective FROM attempts WHERE job_id = :j ORDER BY 1, 2"
    rows = _rows(faults, same, twice)
    assert rows == _rows(faults, same, single["id"])
    logger.info("duplicate delivery: 2 chunks fitted twice at once; angles.csv, histograms.xml and "
                "%d attempt rows equal to the single delivery's", len(rows))


def test_sigterm_mid_chunk_the_worker_finishes_it_before_exiting(faults, slow_ids):
    """Warm shutdown: the running chunks complete (the job with them), then the worker exits."""
    client = _client(faults, slow_ids)
    with worker(faults) as process:
        job = submit(client, slow_ids, chunk_size=60, max_attempts=1)["id"]
        _wait_chunks(faults, job, "running", 2)
        time.sleep(0.5)
        process.send_signal(signal.SIGTERM)
        t0 = time.monotonic()
        code = process.wait(timeout=60)
        exited = time.monotonic() - t0
    assert code == 0
    assert client.get(f"/jobs/{job}").json()["status"] == "succeeded"
    assert _attempts(faults, job) == [1, 1]
    _assert_every_image_once(faults, job, SLOW_IMAGES)
    logger.info("SIGTERM: worker exited %.1f s later, its 2 running chunks finished", exited)


def _multipart_zeros(boundary: str, chunks: int, on_chunk: Callable[[int], None]) -> Iterator[bytes]:
    yield (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"a.avi\"\r\n"
           "Content-Type: video/x-msvideo\r\n\r\n").encode()
    for i in range(chunks):
        on_chunk(i)
        yield bytes(64 * 1024)
        time.sleep(0.01)


def _partials(faults: Deployment) -> list[Path]:
    assert faults.data is not None
    return list((faults.data / "storage").rglob(".partial-*"))


def test_api_killed_during_an_upload_registers_nothing_and_the_retry_succeeds(faults, clip):
    client = faults.create_lab("upload")
    api = faults.processes[0]
    killed = threading.Event()

    def kill_midway(i: int) -> None:
        if i == 40 and not killed.is_set():  # 2.5 MB received
            api.kill()
            api.wait()
            killed.set()

    boundary = "faultsboundary"
    with pytest.raises(httpx.TransportError):
        client.post("/videos", content=_multipart_zeros(boundary, 400, kill_midway),
                    headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert killed.is_set()
    assert len(_partials(faults)) == 1  # what the killed API was writing
    assert _partials(faults)[0].stat().st_size > 0
    faults.processes.remove(api)
    faults.start_api()
    t0 = time.monotonic()
    while True:
        try:
            if client.get("/jobs").status_code == 200:
                break
        except httpx.TransportError:
            assert time.monotonic() - t0 < 60
            time.sleep(0.2)
    restarted = time.monotonic() - t0
    assert _partials(faults) == []  # removed on start
    count = "SELECT count(*) FROM videos v JOIN labs l ON l.id = v.lab_id WHERE l.name = :j"
    assert _rows(faults, count, "upload")[0][0] == 0
    with clip.video.open("rb") as f:
        retry = client.post("/videos", files={"file": ("clip.avi", f, "video/x-msvideo")})
    assert retry.status_code == 201, retry.text
    assert retry.json()["frames"] == 40
    assert _rows(faults, count, "upload")[0][0] == 1
    logger.info("API killed mid-upload: no video row, 1 partial file removed by the restarted API "
                "(up in %.1f s), the retry registered", restarted)
