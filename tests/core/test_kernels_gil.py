"""The compiled kernels release the GIL (issue 12, item 3).

A worker writes its chunk's heartbeat from a Python thread while the chunk's images are
fitted. A kernel that held the GIL for a long fit (minutes for a large model) starved that
thread, the reaper took the healthy chunk for dead and ran it a second time.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from core.anneal import AnnealParams, search_space
from core.error import Detections
from core.examples import LOCUST
from core.fit import FitParams, fit_image, image_stream
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig

TICK_S = 0.005


def _long_fit(model: KinematicModel, rig: Rig, iterations: int) -> None:
    """One fit of the locust model running all ``iterations`` of plain SA (eps 0: no early stop)."""
    truth = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    det = Detections.from_views(list(rig.project(model.marker_positions(truth))))
    anneal = AnnealParams(n_end=iterations, n_l=iterations // 10, n_tau=iterations // 20, eps=0.0,
                          polish_every=0, patience=0)
    params = FitParams(anneal=anneal, restarts=0, refine=False)
    space = search_space(model, Histograms.uniform(model))
    fit_image(det, model=model, rig=rig, space=space, params=params, stream=image_stream(0, 0, 1))


def test_another_thread_runs_while_a_fit_kernel_runs():
    """While one fit (about two seconds of compiled SA) runs in a thread, the main thread keeps
    ticking every 5 ms: at least a quarter of the ticks a free thread would make. Measured on
    a loaded machine: 377 of 440; with a GIL-holding copy of the kernel, 2 in 1.83 s."""
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    rig = Rig.from_json(LOCUST / "rig.json")
    _long_fit(model, rig, 1000)  # compile (or load the cache) outside the measurement
    worker = threading.Thread(target=_long_fit, args=(model, rig, 4_000_000))
    ticks = 0
    start = time.perf_counter()
    worker.start()
    while worker.is_alive():
        time.sleep(TICK_S)
        ticks += 1
    elapsed = time.perf_counter() - start
    assert elapsed > 0.3, f"the fit took {elapsed:.2f} s: too short to show anything"
    assert ticks >= 0.25 * elapsed / TICK_S, f"{ticks} ticks in {elapsed:.2f} s"
