"""Limits that protect the service (issue 5), each set small through ``MOCAP_*`` and hit for real.

One deployment of its own (PostgreSQL, Redis, uvicorn) with tiny limits and no worker, so
submitted jobs stay queued: the active-job cap is reached deterministically. The chunk time
limit test starts a worker with the deployment's settings only for itself.
"""

from __future__ import annotations

import contextlib
import json
import re
import select
import socket
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import urlsplit

import cv2
import numpy as np
import pytest
from conftest import redis_pg_deployment
from svc_helpers import upload_inputs, wait_for

from core.examples import LOCUST
from core.synth import write_video

pytestmark = [pytest.mark.service, pytest.mark.slow]

FILES_PER_HOUR = 3
ACTIVE_JOBS = 2
FRAMES_PER_JOB = 50  # the clip has 40
SOFT_LIMIT_S, HARD_LIMIT_S = 1, 3


@pytest.fixture(scope="module")
def limited(tmp_path_factory, clip):
    """Upload limit 3 clips, hourly bytes 2.5 clips (two pass, the third does not)."""
    size = clip.video.stat().st_size
    with redis_pg_deployment(
        tmp_path_factory.mktemp("limited"), "limited", workers=0,
        max_upload_bytes=str(3 * size), upload_bytes_per_hour=str(int(2.5 * size)),
        upload_files_per_hour=str(FILES_PER_HOUR), max_active_jobs_per_lab=str(ACTIVE_JOBS),
        max_frames_per_job=str(FRAMES_PER_JOB), task_soft_time_limit_s=str(SOFT_LIMIT_S),
        task_time_limit_s=str(HARD_LIMIT_S),
    ) as deployment:
        yield deployment


def _storage(deployment) -> dict[str, int]:
    """Every stored file (partial ones included) and its size."""
    root = Path(deployment.env["MOCAP_DATA_DIR"]) / "storage"
    return {str(p.relative_to(root)): p.stat().st_size for p in root.rglob("*") if p.is_file()}


def _upload(client, path: Path):
    with path.open("rb") as f:
        return client.post("/videos", files={"file": (path.name, f, "video/x-msvideo")})


def _tiny_video(path: Path) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48), False)
    for i in range(5):
        writer.write(np.full((48, 64), 20 * i, dtype=np.uint8))
    writer.release()
    return path


def _batch(ids: dict[str, int]) -> dict:
    return {"model_id": ids["model_id"], "rig_id": ids["rig_id"],
            "trials": [{"video_ids": [ids["video_id"]]}]}


def _assert_429(response, setting: str, most: int) -> None:
    assert response.status_code == 429, response.text
    assert setting in response.json()["detail"], response.json()
    assert 1 <= int(response.headers["Retry-After"]) <= most


def test_uploads_per_hour_are_capped_with_retry_after(limited, tmp_path):
    client = limited.create_lab("files-per-hour")
    video = _tiny_video(tmp_path / "tiny.avi")
    assert [_upload(client, video).status_code for _ in range(FILES_PER_HOUR)] == [201] * FILES_PER_HOUR
    before = _storage(limited)
    _assert_429(_upload(client, video), "MOCAP_UPLOAD_FILES_PER_HOUR", 3600)
    assert _storage(limited) == before
    assert _upload(limited.create_lab("another lab"), video).status_code == 201  # per lab


def test_upload_bytes_per_hour_are_capped_declared_or_streamed(limited, clip):
    """Two clips pass; the third is refused before streaming when its length is declared, and
    after streaming (the file deleted) when it is sent chunked without a length."""
    client = limited.create_lab("bytes-per-hour")
    assert [_upload(client, clip.video).status_code for _ in range(2)] == [201, 201]
    before = _storage(limited)
    _assert_429(_upload(client, clip.video), "MOCAP_UPLOAD_BYTES_PER_HOUR", 3600)
    body = clip.video.read_bytes()

    def chunked():
        yield b'--b\r\nContent-Disposition: form-data; name="file"; filename="c.avi"\r\n\r\n'
        yield body
        yield b"\r\n--b--\r\n"

    streamed = client.post("/videos", content=chunked(),
                           headers={"Content-Type": "multipart/form-data; boundary=b"})
    _assert_429(streamed, "MOCAP_UPLOAD_BYTES_PER_HOUR", 3600)
    assert _storage(limited) == before
    assert len(client.get("/jobs").json()["items"]) == 0


def _raw_request(deployment, client, head: str) -> socket.socket:
    """A socket that has sent a POST /videos request line and headers (with the lab's key)."""
    url = urlsplit(deployment.url)
    s = socket.create_connection((url.hostname, url.port), timeout=10)
    key = client.headers["Authorization"]
    s.sendall(f"POST {url.path}/videos HTTP/1.1\r\nHost: x\r\nAuthorization: {key}\r\n"
              f"Content-Type: multipart/form-data; boundary=b\r\n{head}\r\n".encode())
    return s


def _reply(s: socket.socket) -> str:
    """The response on ``s``: headers and a body of its Content-Length (it may come in pieces)."""
    data = b""
    with contextlib.suppress(ConnectionResetError, TimeoutError):
        while chunk := s.recv(65536):
            data += chunk
            head, _, body = data.partition(b"\r\n\r\n")
            length = re.search(rb"content-length: (\d+)", head, re.IGNORECASE)
            if length and len(body) >= int(length.group(1)):
                break
    return data.decode()


def test_upload_over_the_size_limit_is_413_while_streaming(limited):
    """A body 16 MB over the limit, sent chunked (no length to refuse it by) 1 MB at a time
    (a '4 GB' upload in small): the 413 arrives while the client is still sending, and
    nothing stays on disk."""
    client = limited.create_lab("big")
    limit = int(limited.env["MOCAP_MAX_UPLOAD_BYTES"])
    chunks = limit // (1 << 20) + 16
    before = _storage(limited)
    part = b'--b\r\nContent-Disposition: form-data; name="file"; filename="x.avi"\r\n\r\n'
    with _raw_request(limited, client, "Transfer-Encoding: chunked\r\n") as s:
        s.sendall(b"%x\r\n%s\r\n" % (len(part), part))
        sent = 0
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):  # the server may close first
            while sent < chunks and not select.select([s], [], [], 0.02)[0]:
                s.sendall(b"100000\r\n" + bytes(1 << 20) + b"\r\n")
                sent += 1
        reply = _reply(s)
    assert reply.startswith("HTTP/1.1 413"), reply
    assert "larger than this server accepts" in reply
    assert limit // (1 << 20) <= sent < chunks, (sent, chunks)  # refused once past the limit
    assert _storage(limited) == before  # no partial file, no byte of disk kept


def test_a_declared_4_gib_body_is_413_before_any_byte_is_read(limited):
    client = limited.create_lab("four-gib")
    with _raw_request(limited, client, "Content-Length: 4294967296\r\n") as s:
        s.sendall(b"--b\r\n")
        reply = _reply(s)
    assert reply.startswith("HTTP/1.1 413"), reply
    assert "larger than this server accepts" in reply


def test_frames_per_job_are_capped_at_submission(limited, clip, tmp_path):
    client = limited.create_lab("frames")
    long = tmp_path / "long.avi"
    capture, frames = cv2.VideoCapture(str(clip.video)), []
    while (frame := capture.read())[0]:
        frames.append(cv2.cvtColor(frame[1], cv2.COLOR_BGR2GRAY))
    capture.release()
    write_video(long, frames + frames, fps=50.0)
    ids = upload_inputs(client, long)
    job = {"model_id": ids["model_id"], "rig_id": ids["rig_id"], "video_ids": [ids["video_id"]]}
    for path, body in (("/jobs", job), ("/batches", _batch(ids))):
        response = client.post(path, json=body)
        assert response.status_code == 422, response.text
        detail = response.json()["detail"]
        assert "80 frames" in detail and f"at most {FRAMES_PER_JOB}" in detail
        assert "MOCAP_MAX_FRAMES_PER_JOB" in detail
    assert client.get("/jobs").json()["items"] == []


def test_active_jobs_per_lab_are_capped_until_one_ends(limited, clip):
    """No worker runs here: submitted jobs stay queued, so the cap is reached for certain."""
    client = limited.create_lab("active")
    ids = upload_inputs(client, clip.video)
    job = {"model_id": ids["model_id"], "rig_id": ids["rig_id"], "video_ids": [ids["video_id"]]}
    first = [client.post("/jobs", json=job) for _ in range(ACTIVE_JOBS)]
    assert [r.status_code for r in first] == [202] * ACTIVE_JOBS
    _assert_429(client.post("/jobs", json=job), "MOCAP_MAX_ACTIVE_JOBS_PER_LAB", 60)
    _assert_429(client.post("/batches", json=_batch(ids)), "MOCAP_MAX_ACTIVE_JOBS_PER_LAB", 60)
    assert len(client.get("/jobs").json()["items"]) == ACTIVE_JOBS  # nothing half-created
    assert client.post(f"/jobs/{first[0].json()['id']}/cancel").status_code == 200
    again = client.post("/jobs", json=job)
    assert again.status_code == 202
    for r in (first[1], again):
        client.post(f"/jobs/{r.json()['id']}/cancel")


def test_a_chunk_over_the_time_limit_fails_its_job_with_a_clear_message(limited, clip, tmp_path):
    """MOCAP_TASK_SOFT_TIME_LIMIT_S reaches the worker: a rig no posture fits makes each image
    take ~40 ms, and de-interlacing makes the 40 frames 80 images in one chunk (~3 s), past the
    1 s limit. (More iterations would not do: SA stops once polishing stops gaining.) Planning
    probes the video in ~0.5 s; on a loaded machine it may be the task that passes the limit,
    and the message is the same."""
    client = limited.create_lab("time-limit")
    rig = json.loads((LOCUST / "rig.json").read_text())
    for view in rig["views"]:
        view["projection"]["matrix"][0][0] = 1.5
    ids = upload_inputs(client, clip.video, rig=json.dumps(rig).encode())
    response = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "video_ids": [ids["video_id"]],
                                          "options": {"marker_diameter_px": 4.0, "chunk_size": 80,
                                                      "deinterlace": True, "max_attempts": 1}})
    assert response.status_code == 202, response.text
    log = (tmp_path / "worker.log").open("w")
    worker = subprocess.Popen([sys.executable, "-m", "service.cli", "worker", "--concurrency", "1"],
                              env=limited.env, stdout=log, stderr=subprocess.STDOUT)
    try:
        job = wait_for(client, response.json()["id"], timeout=90)
        # The job fails as soon as the chunk records its failure; the task then re-raises. A
        # warm shutdown before Celery has the task's result fires the soft limit again, into
        # the result's pickling (billiard), and the pool never stops: wait for the result.
        _wait_for_log(tmp_path / "worker.log", r"Task mocap\.fit_chunk\[[^\]]+\] (raised|succeeded)", 30.0)
    finally:
        worker.terminate()
        worker.wait(timeout=30)
    assert job["status"] == "failed", job
    assert (f"the task ran longer than its time limit of {SOFT_LIMIT_S} s (MOCAP_TASK_SOFT_TIME_LIMIT_S); "
            "submit smaller chunks") in job["error"], job["error"]


def _wait_for_log(path: Path, pattern: str, timeout: float) -> None:
    """Wait until a line of the log at ``path`` matches ``pattern`` (at most ``timeout`` s)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if re.search(pattern, path.read_text(errors="replace")):
            return
        time.sleep(0.1)
    raise AssertionError(f"no line of {path.name} matched {pattern!r} in {timeout} s")
