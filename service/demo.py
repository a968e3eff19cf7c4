"""``mocap demo --service``: the demo through the embedded service, as a lab uses it over HTTP.

Renders the locust example into a video, starts ``mocap serve`` on the embedded default
(SQLite and kombu's filesystem broker, real worker processes) in a temporary data
directory, creates a lab, uploads model, rig and video, submits a job, polls it, downloads
``angles.csv`` and prints its accuracy against the truth. Nothing is left behind.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.benchmark import FPS, MARKER_DIAMETER_PX
from core.examples import LOCUST
from core.model import KinematicModel
from core.results import AnglesTable, read_angles_csv
from core.rig import Rig
from core.synth import natural_movements, render_frames, write_video
from service.client import Client, ClientError

STARTUP_S = 120.0  # migrations, worker start-up and a first numba compile on a slow machine


def run_demo(samples: int, seed: int, workers: int) -> None:
    """Render, serve, upload, fit, download and compare; print each step."""
    with tempfile.TemporaryDirectory(prefix="mocap-demo-") as tmp:
        root = Path(tmp)
        truth, video = _render(root / "trial.avi", samples, seed)
        print(f"rendered {samples} images of the locust hind leg into {video.name}", flush=True)
        env = _embedded_env(root / "data")
        key = _create_lab(env)
        port = _free_port()
        log = (root / "serve.log").open("w")
        server = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "serve", "--port", str(port), "--workers", str(workers)],
            env=env, stdout=log, stderr=subprocess.STDOUT)
        try:
            with Client(f"http://127.0.0.1:{port}", key) as api:
                _wait_until_up(api, server, root / "serve.log")
                print(f"embedded service up on port {port} ({workers} worker processes, SQLite, "
                      "filesystem broker)", flush=True)
                angles = _fit_over_http(api, video, seed)
        finally:
            server.send_signal(signal.SIGTERM)
            server.wait(timeout=90)
            log.close()
        (root / "angles.csv").write_bytes(angles)
        _print_accuracy(read_angles_csv(root / "angles.csv"), truth)


def _render(path: Path, samples: int, seed: int) -> tuple[NDArray[np.float64], Path]:
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    rig = Rig.from_json(LOCUST / "rig.json")
    rng = np.random.default_rng(seed)
    truth = natural_movements(model, rig, samples, rng=rng, fps=FPS)
    write_video(path, render_frames(model, rig, truth, rng=rng, marker_diameter_px=MARKER_DIAMETER_PX),
                fps=FPS)
    return truth, path


def _embedded_env(data_dir: Path) -> dict[str, str]:
    """This environment with the service's settings on the embedded default in ``data_dir``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    return env | {"MOCAP_DATA_DIR": str(data_dir)}


def _create_lab(env: dict[str, str]) -> str:
    done = subprocess.run([sys.executable, "-m", "service.cli", "admin", "create-lab", "demo lab"],
                          env=env, capture_output=True, text=True, check=True)
    return done.stdout.strip().splitlines()[-1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_until_up(api: Client, server: subprocess.Popen[bytes], log: Path) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < STARTUP_S:
        if server.poll() is not None:
            raise RuntimeError(f"mocap serve exited with {server.returncode}:\n{log.read_text()[-2000:]}")
        try:
            api.ping()
            return
        except ClientError:
            pass
        time.sleep(0.3)
    raise RuntimeError(f"mocap serve did not answer within {STARTUP_S:.0f} s")


def _fit_over_http(api: Client, video: Path, seed: int) -> bytes:
    """Upload, submit, poll to a terminal status, return angles.csv."""
    model = api.upload_model(LOCUST / "model.xml")
    rig = api.upload_rig(LOCUST / "rig.json")
    uploaded = api.upload_video(video)
    t0 = time.monotonic()
    job = api.submit_job(model["id"], rig["id"], [uploaded["id"]], {"seed": seed})
    print(f"job {job['id']} submitted; on a first run the workers first compile the fitting "
          "kernels, once for all of them (half a minute to a minute and a half on a 2-core machine), "
          "later runs start at once",
          flush=True)
    shown: list[tuple[str, int]] = []

    def report(state: dict[str, Any]) -> None:
        now = (state["status"], state["progress"]["images_done"])
        if not shown or now != shown[-1]:
            print(f"  {time.monotonic() - t0:5.0f} s  {now[0]}, {now[1]}/"
                  f"{state['progress']['images_total']} images", flush=True)
            shown.append(now)

    job = api.wait("job", job["id"], max_interval=0.5, on_poll=report)
    print(f"job {job['id']} {job['status']} in {time.monotonic() - t0:.1f} s: "
          f"{job['progress']['images_done']} images, "
          f"{job['progress']['images_over_threshold']} over threshold", flush=True)
    if job["status"] != "succeeded":
        raise RuntimeError(f"job {job['status']}: {job['error']}")
    return api.result(job["id"], "angles.csv")


def _print_accuracy(table: AnglesTable, truth: NDArray[np.float64]) -> None:
    rmse = np.sqrt(np.nanmean((table.dofs - truth) ** 2, axis=0))
    print("RMSE against the truth (degrees): " + ", ".join(
        f"{name} {value:.3f}" for name, value in zip(table.dof_names, rmse, strict=True)))
    print(f"mean view error {np.nanmean(table.errors):.3f} px; "
          f"{sum(s.value != 'ok' for s in table.statuses)} images not ok")
