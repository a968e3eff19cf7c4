"""A job's options reach the worker as ``mocap fit`` takes them: the same core.options.build_fit,
so a job with root tracking and a prior weight fits exactly as a local run of the same options."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from recorded_queue import CHUNK_SIZE, Recorder

from core.examples import LOCUST
from core.model import KinematicModel
from core.options import FitOptions, build_fit
from core.pipeline import outputs, plan, run_fit
from core.rig import Rig
from service.broker import FIT_CHUNK, REANALYSE_IMAGE
from service.db import session_scope
from service.models import Job, JobStatus
from service.storage import get_storage
from worker import orchestration

OPTIONS = {"chunk_size": CHUNK_SIZE, "marker_diameter_px": 4.0, "max_attempts": 2, "iterations": 7000,
           "seed": 4, "root_marker": "M0", "root_max_jump_px": 15.0, "prior_weight": 40.0}


def _drain(queue: Recorder) -> None:
    while messages := queue.take():
        for name, args in messages:
            run = {FIT_CHUNK: orchestration.run_chunk, REANALYSE_IMAGE: orchestration.run_attempt}[name]
            run(*args, worker="test-worker")


def test_root_tracking_and_prior_weight_are_honoured_as_by_a_local_fit(
    queue: Recorder, submit: Callable[..., int], clip: Path
) -> None:
    job_id = submit(**OPTIONS)
    orchestration.plan_job(job_id)
    _drain(queue)
    with session_scope() as session:
        assert session.get_one(Job, job_id).status == JobStatus.SUCCEEDED
    with get_storage().open(f"jobs/{job_id}/angles.csv") as served:
        served_csv = served.read().decode()

    model, rig = KinematicModel.from_xml(LOCUST / "model.xml"), Rig.from_json(LOCUST / "rig.json")
    local = build_fit(FitOptions(**OPTIONS), model, rig, [clip])
    offsets = plan(local.job).offsets
    assert offsets is not None and np.abs(offsets).max() > 0  # the offsets change every fit
    assert local.start.counts.max() == pytest.approx(40.0)
    # the files a lab reads: the stored rows are each image's fit before the choice by continuity
    assert served_csv == outputs(local.job, run_fit(local.job, local.start)).angles_csv


@pytest.mark.parametrize(("options", "message"), [
    ({"root_marker": "M3"}, "root marker 'M3' must sit at the origin"),
    ({"root_marker": "M0", "root_start": [[240, 184]]}, "root_start has 1 (u, v) pair(s) for a rig of 2"),
])
def test_root_tracking_the_model_or_rig_cannot_have_is_refused_at_submission(
    queue: Recorder, submit: Callable[..., int], options: dict[str, object], message: str
) -> None:
    with pytest.raises(ValueError) as caught:
        submit(**options)
    assert message in str(caught.value)
