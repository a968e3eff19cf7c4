"""A job in a real SQLite database, built by the service's own migrations and service layer,
with the Celery queue replaced by a recorder: ``service.broker.enqueue`` swapped for a
function that appends the message to a list, so a test runs each step by hand (and twice).

No broker, no worker processes: the orchestration's steps run in the test's process, on the
same database and storage a deployment would use (``MOCAP_DATA_DIR`` points at a temporary
folder; the process-wide caches of settings, engine and sessions are cleared around each test).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from recorded_queue import CHUNK_SIZE, IMAGES, MISFIT, Recorder

from core.examples import LOCUST
from core.model import KinematicModel
from core.rig import Rig
from core.synth import natural_movements, render_frames, write_video
from service import broker, crud, db, migrate, settings
from service.labs import create_lab
from service.models import Lab
from service.schemas import JobCreate, JobOptions
from service.storage import get_storage
from worker import orchestration


def _clear_process_caches() -> None:
    for cached in (settings.get_settings, db.get_engine, db.session_factory, db.read_session_factory):
        cached.cache_clear()
    orchestration._core_cache.clear()


@pytest.fixture
def queue(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Recorder]:
    """A migrated SQLite database and storage under ``tmp_path``, and the queue's recorder."""
    monkeypatch.setenv("MOCAP_DATA_DIR", str(tmp_path))
    for name in ("MOCAP_DATABASE_URL", "MOCAP_BROKER_URL", "MOCAP_CRASH_CHUNK"):
        monkeypatch.delenv(name, raising=False)
    _clear_process_caches()
    migrate.upgrade()
    recorder = Recorder()
    monkeypatch.setattr(broker, "enqueue", recorder)
    yield recorder
    db.get_engine().dispose()
    _clear_process_caches()


def _half_scale(rig_json: dict) -> Rig:
    for view in rig_json["views"]:
        for row in view["projection"]["matrix"]:
            row[:3] = [v / 2 for v in row[:3]]
    return Rig.from_dict(rig_json)


@pytest.fixture(scope="session")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The locust example's video of ``IMAGES`` frames, the ``MISFIT`` ones drawn at half scale."""
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    spec = json.loads((LOCUST / "rig.json").read_text())
    rig, wrong = Rig.from_dict(spec), _half_scale(json.loads(json.dumps(spec)))
    rng = np.random.default_rng(3)
    truth = natural_movements(model, rig, IMAGES, rng=rng, n_sequences=1)
    good = list(render_frames(model, rig, truth, rng=rng))
    bad = list(render_frames(model, wrong, truth, rng=rng))
    path = tmp_path_factory.mktemp("clip") / "clip.avi"
    write_video(path, (bad[i] if i in MISFIT else good[i] for i in range(IMAGES)), fps=50.0)
    return path


@pytest.fixture
def submit(queue: Recorder, clip: Path) -> Callable[..., int]:
    """Submit a queued job on ``clip`` with these options through the service layer, as the API
    does; its id."""

    def submit_job(**options: Any) -> int:
        config = settings.get_settings()
        storage = get_storage()
        with db.session_scope() as session:
            lab, _ = create_lab(session, "lab")
            session.commit()
            model = crud.create_model(session, storage, lab, (LOCUST / "model.xml").read_bytes())
            rig = crud.create_rig(session, lab, json.loads((LOCUST / "rig.json").read_text()))
            storage.put("videos/clip.avi", [clip.read_bytes()])
            video = crud.register_video(session, storage, lab, config, key="videos/clip.avi",
                                        filename="clip.avi", size=clip.stat().st_size, sha256="0" * 64)
            body = JobCreate(model_id=model.id, rig_id=rig.id, video_ids=[video.id],
                             options=JobOptions.model_validate(options))
            job = crud.submit_job(session, session.get_one(Lab, lab.id), config, body)
            return job.id

    return submit_job


@pytest.fixture
def job_id(submit: Callable[..., int]) -> int:
    """A queued job on ``clip`` submitted through the service layer, as the API does."""
    return submit(chunk_size=CHUNK_SIZE, marker_diameter_px=4.0, max_attempts=2)
