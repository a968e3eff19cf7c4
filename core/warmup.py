"""Compile (or load from numba's on-disk cache) every kernel a fit runs, once, up front.

numba compiles a kernel the first time it is called with a new signature and
caches the machine code next to the source. Worker processes that start cold
would each compile the same kernels at their first image. A process that calls
:func:`compile_kernels` before forking its workers (Celery's prefork pool, a
process pool started with ``fork``) compiles once; the children inherit the
compiled code, and later runs load it from the cache. On a first run (no cache yet) a
second process meanwhile compiles part of the kernels into the cache, where this process
loads them (waiting for those SA's compile needs rather than compiling them twice): the
machine's second core shortens a first run (``bench/speed.py`` measures it).

The warm-up goes through the same public functions as a real fit (detection,
a single chain, a tree with a free root, fusion on), so the signatures match. It needs no
file: the models and the rig are written here.

It compiles at LLVM's optimisation level :data:`OPT_LEVEL` rather than numba's default 3
(unless ``NUMBA_OPT`` is set: the user's choice stands): the first run's compile is 10 %
shorter, and the kernels run as fast (``bench/speed.py``; figures in docs/ENGINE_NOTES.md).
"""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from numba.core import config
from numba.core.registry import CPUDispatcher as Dispatcher

from core import _detect_kernels, _epipolar_kernels, _kernels
from core.ambiguity import Candidate, FlipGeometry, flip_alternatives
from core.detect import detect
from core.error import Detections, view_error, view_offsets
from core.fields import detect_fields
from core.fit import FitParams, image_stream
from core.histogram import Histograms
from core.model import KinematicModel
from core.part_objective import world_frames
from core.refine import refine
from core.rig import Rig
from core.sequence import fit_sequence

__all__ = ["compile_kernels", "compile_kernels_saying_so"]

_ROOT = Path(__file__).resolve().parents[1]  # holds the package core
OPT_LEVEL = 1  # LLVM optimisation level of the kernels compiled here (numba's NUMBA_OPT)
# The cycle collector's thresholds while compiling (Python's default: 700, 10, 10): the same
# first run as with the collector off, at a tenth of the memory that costs (docs/ENGINE_NOTES.md).
COMPILE_GC_THRESHOLDS = (20000, 20, 1000)

FIRST_RUN = ("compiling the fitting kernels, once (half a minute to a minute and a half on a 2-core "
             "machine, more if it is busy; later runs load them from numba's cache in about a second)")

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
    """Run a few tiny fits so that every kernel is compiled or loaded; returns the seconds taken.

    With an empty cache, a second process (:func:`_compile_aside`) compiles the objective and
    the lost-marker search into numba's cache while this one renders the warm-up images and
    compiles refinement; this one waits for those two (SA's polish calls all three) and
    loads them, instead of compiling them a second time, then compiles SA. The machine's
    second core takes part of a first run.
    """
    t0 = time.perf_counter()
    aside = None if _cache_filled() else subprocess.Popen(
        [sys.executable, "-c", "from core.warmup import _compile_aside; _compile_aside()"],
        env={"NUMBA_OPT": str(OPT_LEVEL)} | os.environ
        | {"PYTHONPATH": os.pathsep.join([str(_ROOT), os.environ.get("PYTHONPATH", "")])},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        with _optimisation_level(), _fewer_collections():
            _warm_up(aside)
    finally:
        if aside is not None:
            aside.wait()  # it only adds to the cache: its outcome changes nothing here
    return time.perf_counter() - t0


def _warm_up(aside: subprocess.Popen[bytes] | None) -> None:
    """:func:`compile_kernels`' fits and detections in this process, waiting for the kernels
    ``aside`` (None: the cache is filled) compiles where it reaches them."""
    rig, chain, tree = _rig(), KinematicModel.from_xml(_CHAIN), KinematicModel.from_xml(_TREE)
    chain_images, tree_images = _images(chain, rig), _images(tree, rig)
    refine(_posture(chain), _blobs(), model=chain, rig=rig, fusion_px=8.0)
    if aside is not None:
        _wait_for_cache(aside, (_kernels.posture_error, _kernels._lost_markers))
    _fit(chain, rig, chain_images)
    if aside is not None:  # its last kernel, for the tree's two-view starts, and the fields'
        _wait_for_cache(aside, (_epipolar_kernels.beam_search, _detect_kernels.fit_field_discs))
    _fit(tree, rig, tree_images)
    _detect(rig)
    _detect_fields(rig)


def _fit(m: KinematicModel, rig: Rig, images: list[Detections]) -> None:
    """A short fit of ``images``, fusion on, two attempts."""
    params = FitParams(anneal=FitParams().anneal.with_iterations(300), fusion_px=8.0, max_attempts=2)
    fit_sequence(images, model=m, rig=rig, histograms=Histograms.uniform(m), params=params, seed=0)


@contextmanager
def _fewer_collections() -> Iterator[None]:
    """Python's cycle collector runs at :data:`COMPILE_GC_THRESHOLDS` inside, its thresholds
    before restored after. Compiling allocates millions of objects, and at the default
    thresholds the collector's passes over them were some 5 s of a first run's 30 under
    ``mocap``'s console script (docs/ENGINE_NOTES.md)."""
    saved = gc.get_threshold()
    gc.set_threshold(*COMPILE_GC_THRESHOLDS)
    try:
        yield
    finally:
        gc.set_threshold(*saved)


@contextmanager
def _optimisation_level() -> Iterator[None]:
    """numba compiles at LLVM level :data:`OPT_LEVEL` inside, unless ``NUMBA_OPT`` is set; its
    level before is restored after. numba reads ``config.OPT`` at every compile and keeps a
    value set in its config module (its ``reload_config`` rereads only a changed environment)."""
    saved = config.OPT
    if "NUMBA_OPT" not in os.environ:
        config.OPT = type(saved)(OPT_LEVEL)
    try:
        yield
    finally:
        config.OPT = saved


def _compile_aside() -> None:
    """Into numba's cache: the nested readings (refinement in the first process reaches them
    some 3 s in), the objective, the posture draw and the lost-marker search (the first
    process waits for them: SA calls them), detection and the de-interlaced fields'
    detection, then, once the first process has cached refinement (compiling it here too
    would take longer than the wait), what calls it: the refit without lost markers (the
    attempt calls it), depth flips; the tree's joint frames; last the beam search of
    triangulated starts, which the first process waits for before the tree."""
    gc.set_threshold(*COMPILE_GC_THRESHOLDS)  # as in the first process; this one ends after
    rig, m = _rig(), KinematicModel.from_xml(_CHAIN)
    det, q = _blobs(), _posture(m)
    _nested_readings(m, rig, det)
    view_error(q, det, model=m, rig=rig, fusion_px=8.0)
    image = _kernels.Image.of(det.kernel_points, det.start, view_offsets(None, rig), penalty=1.0, fuse_px=8.0)
    _draw(m)
    _kernels._lost_markers(q, m.arrays, rig.arrays, image, 1.0, False)
    _detect(rig)
    _detect_fields(rig)
    _wait_for_cache(None, (_kernels.refine,))
    _kernels._refit_unseen(q, np.inf, _kernels.Bounds(m.lower, m.upper), m.arrays, rig.arrays, image, 1.0)
    flip_alternatives(Candidate(q, 1.0, 1.0), det, model=m, rig=rig, geometry=FlipGeometry.of(m, rig),
                      tolerance_px=1e9, fusion_px=8.0, empty_view_penalty_px=1.0, huber_px=1.0)
    world_frames(q, m)
    _beam_search(m, rig, image)


def _beam_search(m: KinematicModel, rig: Rig, image: _kernels.Image) -> None:
    """``_epipolar_kernels.beam_search`` called as ``core.epipolar_start`` calls it: ``m``
    posed onto its own markers, every candidate allowed everywhere."""
    q = _posture(m)
    targets = m.marker_positions(q[None])[0]
    K, M = len(targets), len(m.markers)
    _epipolar_kernels.beam_search(np.arange(M), q, m.arrays, _kernels.Bounds(m.lower, m.upper), rig.arrays,
                                  image, targets, np.ones(K), np.ones((K, K)), np.zeros(K),
                                  np.zeros((M + 1, M + 1)), np.ones((M + 1, M + 1)), 1.0, 2, 2, 2)


def _nested_readings(m: KinematicModel, rig: Rig, det: Detections) -> None:
    """``_kernels._nested_reading`` called as refinement and the objective call it (zero
    projections: nothing to merge)."""
    work = _kernels.workspace(m.arrays, rig.arrays, len(m.dofs), len(det.kernel_points))
    work.raw[:], work.fused[:] = 0.0, 0.0
    _kernels._nested_reading(work.raw, work.fused, 0, det.kernel_points, 0, 0, 64.0, 0.0, np.inf,
                             _kernels.NO_UNSEEN, work.index, work.dist, work.claims)


def _wait_for_cache(writer: subprocess.Popen[bytes] | None, kernels: tuple[Dispatcher, ...],
                    timeout_s: float = 300.0) -> None:
    """Until numba's cache holds an entry of every one of ``kernels`` (or the process
    ``writer`` compiling them has ended, or ``timeout_s`` has passed; None: the first
    process, which this one cannot watch): loading an entry costs far less than compiling
    the kernel again."""
    deadline = time.monotonic() + timeout_s
    while ((writer is None or writer.poll() is None) and time.monotonic() < deadline
           and not all(map(_cached, kernels))):
        time.sleep(0.1)


def _cached(kernel: Dispatcher) -> bool:
    """True if numba's cache holds current compiled code of ``kernel``: an entry of its index
    that numba does not drop as stale (older than the source), whose data file (written after
    the index) is there."""
    try:  # numba's own reading, stale check included; private, so a numba that moved it reads as
        # "not cached": a second process more on a first run, never a failed warm-up
        index = kernel._cache._cache_file._load_index()
    except (AttributeError, OSError):
        return False
    return any((Path(kernel.stats.cache_path) / name).exists() for name in index.values())


def _cache_filled() -> bool:
    """True if numba's cache holds the attempt kernel, current (not a first run, nor a run after
    ``core/_kernels.py`` changed)."""
    return _cached(_kernels.fit_attempt)


def _rig() -> Rig:
    return Rig.from_json(json.dumps({"views": [  # a mirror rig: two views of one frame
        {"name": "side", "video": 0, "roi": [0, 0, 720, 288],
         "projection": {"type": "affine", "matrix": [[3, 0, 0, 360], [0, -3, 0, 144]]}},
        {"name": "top", "video": 0, "roi": [0, 288, 720, 288],
         "projection": {"type": "affine", "matrix": [[3, 0, 0, 360], [0, 0, 3, 432]]}}]}))


def _posture(m: KinematicModel) -> np.ndarray:
    """A posture inside ``m``'s limits, (D,) degrees."""
    return m.lower + 0.35 * (m.upper - m.lower)


def _blobs() -> Detections:
    """Three blobs in each view of :func:`_rig`, placed by hand (rendering them would compile
    the kernels of projection first)."""
    return Detections.from_views([[(360, 144), (390, 150), (420, 160)], [(360, 432), (390, 440), (420, 450)]])


def _images(m: KinematicModel, rig: Rig) -> list[Detections]:
    """Three images of ``m`` moving a little, rendered without noise."""
    postures = np.linspace(m.lower + 0.3 * (m.upper - m.lower), m.lower + 0.4 * (m.upper - m.lower), 3)
    return [Detections.from_views(list(p)) for p in rig.project(m.marker_positions(postures))]


def _draw(m: KinematicModel) -> None:
    """A posture drawn from uniform histograms (D, 36), as an attempt's restart draws one."""
    hist = np.full((len(m.dofs), 36), 1.0 / 36)
    _kernels.draw_posture(m.lower, m.upper, hist, image_stream(0, 0, 0), np.empty(len(m.dofs)))


def _frame() -> np.ndarray:
    """A PAL frame (576, 720) uint8 with one blob."""
    frame = np.zeros((576, 720), dtype=np.uint8)
    frame[100:104, 100:104] = 255
    return frame


def _detect(rig: Rig) -> None:
    detect([_frame()], rig=rig)


def _detect_fields(rig: Rig) -> None:
    """Detection of the two de-interlaced fields of a frame (the paper's PAL DV): the fields'
    disc fits are kernels of their own (``core.fields``)."""
    detect_fields([_frame()], rig=rig)


def compile_kernels_saying_so(say: Callable[[str], object]) -> float:
    """:func:`compile_kernels`, telling ``say`` (print, a log) before and after; returns the seconds."""
    say(FIRST_RUN)
    seconds = compile_kernels()
    say(f"fitting kernels ready in {seconds:.1f} s")
    return seconds
