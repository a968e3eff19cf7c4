"""Compile (or load from numba's on-disk cache) every kernel a fit runs, once, up front.

numba compiles a kernel the first time it is called with a new signature and
caches the machine code next to the source. Worker processes that start cold
would each compile the same kernels at their first image. A process that calls
:func:`compile_kernels` before forking its workers (Celery's prefork pool, a
process pool started with ``fork``) compiles once; the children inherit the
compiled code, and later runs load it from the cache.

The warm-up goes through the same public functions as a real fit (detection,
a single chain, a tree with a free root, fusion on), so the signatures match. It needs no
file: the models and the rig are written here.
"""

from __future__ import annotations

import json
import time

import numpy as np

from core.detect import detect
from core.error import Detections
from core.fit import FitParams, fit_sequence
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["compile_kernels"]

_CHAIN = """<model name="warmup_chain" units="mm">
  <joint name="base"><dof axis="y" name="p" min="120" max="220"/>
    <dof axis="x" name="q" min="-40" max="40"/></joint>
  <joint name="knee" parent="base"><offset x="10" y="0" z="0"/>
    <dof axis="z" name="k" min="20" max="160"/></joint>
  <joint name="tip" parent="knee"><offset x="10" y="0" z="0"/></joint>
  <marker name="m0" joint="base" x="0" y="0" z="0"/>
  <marker name="m1" joint="knee" x="0" y="0" z="0"/>
  <marker name="m2" joint="tip" x="0" y="0" z="0"/>
</model>"""

_TREE = """<model name="warmup" units="mm">
  <joint name="root"><dof axis="tx" name="tx" min="-5" max="5"/>
    <dof axis="z" name="yaw" min="-30" max="30"/></joint>
  <joint name="a" parent="root"><offset x="5" y="0" z="0"/>
    <dof axis="z" name="a1" min="-40" max="40"/></joint>
  <joint name="a_tip" parent="a"><offset x="10" y="0" z="0"/></joint>
  <joint name="b" parent="root"><offset x="-5" y="0" z="0"/><rest y="0" x="0" z="180"/>
    <dof axis="z" name="b1" min="-40" max="40"/></joint>
  <joint name="b_tip" parent="b"><offset x="10" y="0" z="0"/></joint>
  <marker name="r0" joint="root" x="0" y="2" z="0"/>
  <marker name="r1" joint="root" x="2" y="-1" z="0"/>
  <marker name="r2" joint="root" x="-2" y="-1" z="1"/>
  <marker name="a" joint="a_tip" x="0" y="0" z="0"/>
  <marker name="b" joint="b_tip" x="0" y="0" z="0"/>
</model>"""


def compile_kernels() -> float:
    """Run a few tiny fits so that every kernel is compiled or loaded; returns the seconds taken."""
    t0 = time.perf_counter()
    rig = Rig.from_json(json.dumps({"views": [  # a mirror rig: two views of one frame
        {"name": "side", "video": 0, "roi": [0, 0, 720, 288],
         "projection": {"type": "affine", "matrix": [[3, 0, 0, 360], [0, -3, 0, 144]]}},
        {"name": "top", "video": 0, "roi": [0, 288, 720, 288],
         "projection": {"type": "affine", "matrix": [[3, 0, 0, 360], [0, 0, 3, 432]]}}]}))
    frame = np.zeros((576, 720), dtype=np.uint8)
    frame[100:104, 100:104] = 255
    detect([frame], rig=rig)
    for m in (KinematicModel.from_xml(_CHAIN), KinematicModel.from_xml(_TREE)):
        postures = np.linspace(m.lower + 0.3 * (m.upper - m.lower), m.lower + 0.4 * (m.upper - m.lower), 3)
        images = [Detections.from_views(list(p)) for p in rig.project(m.marker_positions(postures))]
        params = FitParams(anneal=FitParams().anneal.with_iterations(300), fusion_px=8.0, max_attempts=2)
        fit_sequence(images, model=m, rig=rig, histograms=Histograms.uniform(m), params=params, seed=0)
    return time.perf_counter() - t0
