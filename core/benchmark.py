"""The locust benchmark of paper §3.2: used by ``mocap demo`` and the benchmarks.

668 samples of natural-looking movement (10 concatenated sequences of smooth
movements with fast extensions) of the Fig. 5 locust hind leg, rendered with
4 px markers into two orthographic views of one 720×576 frame, then detected.
Deterministic for a seed. Interlaced, the 668 samples are the fields of 334 PAL DV
frames, written to a file and read back as ``mocap fit --deinterlace`` reads them.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.detect import detect
from core.error import Detections, fusion_distance
from core.examples import LOCUST
from core.model import KinematicModel
from core.pipeline import VideoSource
from core.rig import Rig
from core.synth import natural_movements, render_frames, write_video

N_SAMPLES = 668
FPS = 50.0
MARKER_DIAMETER_PX = 4.0  # as rendered
FUSION_PX = fusion_distance(MARKER_DIAMETER_PX)  # FitParams.fusion_px for these markers


@dataclass
class Benchmark:
    """A rendered, detected benchmark and its ground truth."""

    model: KinematicModel
    rig: Rig
    truth: np.ndarray  # (T, D) degrees, model order
    detections: list[Detections]
    detect_seconds: float  # detection alone, all images



def locust_benchmark(seed: int = 2004, n_samples: int = N_SAMPLES, *, interlaced: bool = False) -> Benchmark:
    """Render and detect the benchmark (deterministic for a seed); ``interlaced``: as PAL DV fields."""
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    rig = Rig.from_json(LOCUST / "rig.json")
    rng = np.random.default_rng(seed)
    truth = natural_movements(model, rig, n_samples, rng=rng, n_sequences=10, fps=FPS)
    frames = render_frames(model, rig, truth, marker_diameter_px=MARKER_DIAMETER_PX, rng=rng,
                           interlaced=interlaced)
    detections, seconds = _fields_of_dv(frames, rig) if interlaced else _detect_frames(frames, rig)
    return Benchmark(model, rig, truth, detections, seconds)


def _detect_frames(frames, rig: Rig) -> tuple[list[Detections], float]:
    detections, seconds = [], 0.0
    for frame in frames:
        t0 = time.perf_counter()
        detections.append(detect([frame], rig=rig))
        seconds += time.perf_counter() - t0
    return detections, seconds


def _fields_of_dv(frames, rig: Rig) -> tuple[list[Detections], float]:
    """Write the frames as PAL DV, then decode and detect both fields of each (timed together)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "benchmark.avi"
        write_video(path, frames, fps=FPS / 2, codec="dvsd")
        source = VideoSource((path,), rig, deinterlace=True)
        t0 = time.perf_counter()
        detections = list(source[0:len(source)])
        return detections, time.perf_counter() - t0


def single_view(rig: Rig, detections: list[Detections], view: int) -> tuple[Rig, list[Detections]]:
    """The same benchmark seen by one view only."""
    sub = Rig((rig.views[view],))
    return sub, [d.views([view]) for d in detections]


def detection_rms_px(bench: Benchmark) -> float:
    """RMS distance of every true marker projection to its nearest detection (paper: 0.43 px)."""
    proj = bench.rig.project(bench.model.marker_positions(bench.truth))  # (T, V, M, 2)
    d2 = []
    for t, det in enumerate(bench.detections):
        for v in range(len(bench.rig.views)):
            pts = det.view(v)
            if len(pts):
                diff = proj[t, v][:, None, :] - pts[None, :, :]
                d2.extend(np.min(np.sum(diff**2, axis=2), axis=1))
    return float(np.sqrt(np.mean(d2)))
