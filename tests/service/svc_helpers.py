"""HTTP steps shared by the service tests: upload, submit, poll."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import cv2
import httpx

from core.examples import LOCUST
from core.synth import write_video

TERMINAL = {"succeeded", "failed", "canceled"}


def upload_inputs(client: httpx.Client, video: Path, rig: bytes | None = None) -> dict[str, int]:
    """Upload the locust model, a rig (the example's by default) and ``video``; return their ids."""
    model = client.post("/models", content=(LOCUST / "model.xml").read_bytes(),
                        headers={"Content-Type": "application/xml"})
    assert model.status_code == 201, model.text
    rig_response = client.post("/rigs", content=rig or (LOCUST / "rig.json").read_bytes(),
                               headers={"Content-Type": "application/json"})
    assert rig_response.status_code == 201, rig_response.text
    with video.open("rb") as f:
        uploaded = client.post("/videos", files={"file": (video.name, f, "video/x-msvideo")})
    assert uploaded.status_code == 201, uploaded.text
    return {"model_id": model.json()["id"], "rig_id": rig_response.json()["id"],
            "video_id": uploaded.json()["id"]}


def submit(client: httpx.Client, ids: dict[str, int], **options: Any) -> dict[str, Any]:
    response = client.post("/jobs", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "video_ids": [ids["video_id"]], "options": options})
    assert response.status_code == 202, response.text
    assert response.headers["Location"] == f"/v1/jobs/{response.json()['id']}"
    return response.json()


def wait_for(client: httpx.Client, job_id: int, statuses: set[str] = TERMINAL,
             timeout: float = 120.0) -> dict[str, Any]:
    """Poll the job until its status is in ``statuses``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        job = client.get(f"/jobs/{job_id}").json()
        if job["status"] in statuses:
            return job
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} still {job['status']} after {timeout} s: {job}")


def repeated(video: Path, times: int, out: Path) -> Path:
    """The clip's frames ``times`` over: a long video without rendering it."""
    capture, frames = cv2.VideoCapture(str(video)), []
    while (frame := capture.read())[0]:
        frames.append(cv2.cvtColor(frame[1], cv2.COLOR_BGR2GRAY))
    capture.release()
    write_video(out, (f for _ in range(times) for f in frames), fps=50.0)
    return out


def slow_rig() -> bytes:
    """The example rig at half the true scale: no posture explains the markers, so every image
    runs all its iterations (~40 ms): chunks that last long enough to kill mid-way."""
    rig = json.loads((LOCUST / "rig.json").read_text())
    for view in rig["views"]:
        view["projection"]["matrix"][0][0] = 1.5
    return json.dumps(rig).encode()
