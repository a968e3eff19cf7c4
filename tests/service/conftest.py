"""Real deployments for the service tests: API and Celery worker processes, no mocks.

- ``redis_pg``: uvicorn + ``mocap worker`` against PostgreSQL (a schema of its own,
  dropped afterwards) and Redis (db 9, a queue named for this run).
- ``embedded``: ``mocap serve`` as a user runs it: SQLite and kombu's filesystem
  transport under a temporary data dir, migrations on start.
- ``faults`` (module): the ``redis_pg`` layout on a Redis db of its own (the tests flush
  it), reaper timeouts of seconds, and workers the tests start, kill and stop themselves.

With ``CI=true`` a missing PostgreSQL or Redis fails the tests; elsewhere they skip.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import pytest
from sqlalchemy import Engine, text
from sqlalchemy.orm import Session
from svc_helpers import submit, upload_inputs, wait_for

from core.examples import LOCUST
from core.model import KinematicModel
from core.rig import Rig
from core.synth import natural_movements, render_frames, write_video
from service.db import make_engine
from service.labs import create_lab

PG_ADMIN_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
REDIS_URL = "redis://127.0.0.1:6379/9"
REDIS_FAULTS_URL = "redis://127.0.0.1:6379/10"  # FLUSHDB'd by the fault tests
CLIP_IMAGES = 40
CLIP_SEED = 11
UPLOAD_LIMIT = 128 * 1024**2  # the cancel test uploads ~80 MB; the 413 test sends 200 MB


def _reachable(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1):
            return True
    except OSError:
        return False


def require_servers() -> None:
    """PostgreSQL and Redis on 127.0.0.1, or a failure (CI) / skip (laptop) saying which is down."""
    down = [name for name, port in (("PostgreSQL", 5432), ("Redis", 6379)) if not _reachable(port)]
    if not down:
        return
    message = f"{' and '.join(down)} not reachable on 127.0.0.1 (start them: see .ci/run)"
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(message)
    pytest.skip(message)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Deployment:
    """A running service: its URL, environment, database and the processes to stop."""

    name: str
    url: str
    env: dict[str, str]
    database_url: str
    processes: list[subprocess.Popen] = field(default_factory=list)
    engine: Engine | None = None
    data: Path | None = None

    def start_api(self) -> subprocess.Popen:
        """uvicorn on this deployment's port, as the ``redis_pg`` layout runs it."""
        assert self.data is not None
        port = self.url.removesuffix("/v1").rsplit(":", 1)[1]
        api = subprocess.Popen(
            [sys.executable, "-m", "service.api.server", "--port", port, "--log-level", "warning"],
            env=self.env, stdout=(self.data / "api.log").open("a"),
            stderr=subprocess.STDOUT)
        self.processes.append(api)
        return api

    def start_worker(self, concurrency: int = 2, **extra_env: str) -> subprocess.Popen:
        """``mocap worker`` in a process group of its own, so a test can kill it whole."""
        assert self.data is not None
        worker = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "worker", "--concurrency", str(concurrency)],
            env=self.env | extra_env, stdout=(self.data / "worker.log").open("a"),
            stderr=subprocess.STDOUT, start_new_session=True)
        self.processes.append(worker)
        return worker

    def create_lab(self, name: str) -> httpx.Client:
        """A client carrying the key of a new lab, created in this deployment's database by
        the function ``mocap admin create-lab`` calls (``service.labs.create_lab``; the
        command itself is tested in ``test_admin_cli.py``). In this process: a ``mocap``
        process per lab took 1.5-2 s, a fifth of these tests' time."""
        with Session(self.db()) as session, session.begin():
            _, key = create_lab(session, name)
        return httpx.Client(base_url=self.url, headers={"Authorization": f"Bearer {key}"}, timeout=30)

    def db(self) -> Engine:
        if self.engine is None:
            self.engine = make_engine(self.database_url)
        return self.engine

    def stop(self) -> None:
        for p in self.processes:
            p.terminate()
        for p in self.processes:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        if self.engine is not None:
            self.engine.dispose()


def wait_healthy(deployment: Deployment, timeout: float = 60.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        for p in deployment.processes:
            if p.poll() is not None:
                raise RuntimeError(f"{deployment.name}: process {p.args} exited with {p.returncode}")
        try:
            if httpx.get(deployment.url.removesuffix("/v1") + "/openapi.json", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise RuntimeError(f"{deployment.name}: the API did not come up in {timeout} s")


def _base_env(data_dir: Path) -> dict[str, str]:
    env = dict(os.environ)
    env.update(MOCAP_DATA_DIR=str(data_dir), MOCAP_DEFAULT_CHUNK_SIZE="10", MOCAP_HEARTBEAT_S="0.5",
               MOCAP_CANCEL_CHECK_S="0.2", MOCAP_MAX_UPLOAD_BYTES=str(UPLOAD_LIMIT),
               PYTHONUNBUFFERED="1")
    return env


def _worker(env: dict[str, str], log: Path, concurrency: int = 2) -> subprocess.Popen:
    command = [sys.executable, "-m", "service.cli", "worker", "--concurrency", str(concurrency)]
    return subprocess.Popen(command, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)


@contextmanager
def redis_pg_deployment(data: Path, name: str, *, redis_url: str = REDIS_URL, workers: int = 2,
                        **settings: str) -> Iterator[Deployment]:
    """uvicorn + ``mocap worker --concurrency workers`` (none for 0) on a PostgreSQL schema of its
    own (dropped afterwards) and ``redis_url`` with a queue of its own, with ``MOCAP_<NAME>``
    overrides from ``settings``."""
    require_servers()
    schema = f"mocap_test_{uuid.uuid4().hex[:10]}"
    admin = make_engine(PG_ADMIN_URL)
    with admin.begin() as conn:
        conn.execute(text(f'CREATE SCHEMA "{schema}"'))
    env = _base_env(data)
    env.update(MOCAP_DATABASE_URL=f"{PG_ADMIN_URL}?options=-csearch_path%3D{schema}",
               MOCAP_BROKER_URL=redis_url, MOCAP_QUEUE=f"mocap-test-{uuid.uuid4().hex[:10]}")
    env.update({f"MOCAP_{key.upper()}": value for key, value in settings.items()})
    subprocess.run([sys.executable, "-m", "service.migrate"], env=env, check=True, capture_output=True)
    deployment = Deployment(name, f"http://127.0.0.1:{free_port()}/v1", env, env["MOCAP_DATABASE_URL"],
                            data=data)
    deployment.start_api()
    if workers:
        deployment.processes.append(_worker(env, data / "worker.log", workers))
    try:
        wait_healthy(deployment)
        yield deployment
    finally:
        deployment.stop()
        with admin.begin() as conn:
            conn.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))
        admin.dispose()


@pytest.fixture(scope="session")
def redis_pg(tmp_path_factory) -> Iterator[Deployment]:
    with redis_pg_deployment(tmp_path_factory.mktemp("redis_pg"), "redis_pg") as deployment:
        yield deployment


@pytest.fixture(scope="module")
def faults(tmp_path_factory) -> Iterator[Deployment]:
    """Heartbeats stale after 2 s, lost messages sent again after 5 s (planning on a cold worker
    takes ~3 s), a reaper pass every 0.3 s."""
    with redis_pg_deployment(tmp_path_factory.mktemp("faults"), "faults", redis_url=REDIS_FAULTS_URL,
                             workers=0, heartbeat_timeout_s="2", queued_timeout_s="5",
                             reap_interval_s="0.3") as deployment:
        yield deployment


def serve_embedded(data: Path, port: int, workers: int = 2) -> Deployment:
    """``mocap serve`` on ``port`` with its data (SQLite, broker, files) in ``data``, once it answers;
    started again on the same ``data`` it finds everything as it was (the caller stops it)."""
    data.mkdir(parents=True, exist_ok=True)
    env = _base_env(data)
    for name in ("MOCAP_DATABASE_URL", "MOCAP_BROKER_URL", "MOCAP_QUEUE"):
        env.pop(name, None)
    deployment = Deployment("embedded", f"http://127.0.0.1:{port}/v1", env,
                            f"sqlite:///{data / 'mocap.db'}")
    deployment.processes.append(subprocess.Popen(
        [sys.executable, "-m", "service.cli", "serve", "--port", str(port), "--workers", str(workers)],
        env=env, stdout=(data / "serve.log").open("a"), stderr=subprocess.STDOUT))
    try:
        wait_healthy(deployment)
    except RuntimeError:
        deployment.stop()
        raise
    return deployment


@pytest.fixture(scope="session")
def embedded(tmp_path_factory) -> Iterator[Deployment]:
    deployment = serve_embedded(tmp_path_factory.mktemp("embedded"), free_port())
    try:
        yield deployment
    finally:
        deployment.stop()


@pytest.fixture(scope="session")
def owner_job(redis_pg, clip):
    """Lab "owner": its model, rig, video, a succeeded job and a batch (submitted, not awaited)."""
    client = redis_pg.create_lab("owner")
    ids = upload_inputs(client, clip.video)
    job = wait_for(client, submit(client, ids, marker_diameter_px=4.0, chunk_size=40, plots=True)["id"])
    assert job["status"] == "succeeded", job
    batch = client.post("/batches", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "trials": [{"video_ids": [ids["video_id"]]}],
                                          "options": {"chunk_size": 40}})
    assert batch.status_code == 202
    return client, {**ids, "job_id": job["id"], "batch_id": batch.json()["id"]}


@dataclass(frozen=True)
class Clip:
    """A rendered locust clip on disk and its truth."""

    video: Path
    model: KinematicModel
    rig: Rig
    truth: np.ndarray


@pytest.fixture(scope="session")
def clip(tmp_path_factory) -> Clip:
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    rig = Rig.from_json(LOCUST / "rig.json")
    rng = np.random.default_rng(CLIP_SEED)
    truth = natural_movements(model, rig, CLIP_IMAGES, rng=rng, n_sequences=2)
    video = tmp_path_factory.mktemp("clip") / "clip.avi"
    write_video(video, render_frames(model, rig, truth, rng=rng), fps=50.0)
    return Clip(video, model, rig, truth)
