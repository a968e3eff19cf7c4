"""Calibrate and check ``core.cost``: the time of the kernels' units against model size.

    python bench/cost.py [--sizes 5 20 50 100 200] [--views 2] [--lm-sizes 5 50 200 500 1000]

Chain models of J joints (one rotational DOF and one marker each) seen by V orthographic
views, detections the model's own projection. Prints, per size, the measured time of one
Eq. 5 evaluation (``posture_error``) and of one Levenberg–Marquardt step (``refine``, one
iteration) next to ``core.cost``'s figures, and for the smaller sizes the time of one
whole attempt (``fit_image`` with flip alternatives, Table 1 defaults) against the
estimate's upper bound, and the depth-flip search with and without its bound
(``core.ambiguity.MAX_FLIP_REFINES``). Compilation is excluded (a warm-up runs first); one core.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core import _kernels, ambiguity
from core.ambiguity import MAX_FLIP_REFINES, Candidate, FlipGeometry, flip_alternatives
from core.anneal import search_space
from core.cost import estimate_fit_cost
from core.error import Detections
from core.fit import FitParams, fit_image, image_stream
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig


def chain(n: int) -> KinematicModel:
    """``n`` joints in a chain, 1 unit apart along x, one z DOF (-30..30°) and one marker each."""
    free = 'min="-30" max="30"'
    joints = ['<joint name="j0"><dof axis="z" name="d0" min="-30" max="30"/></joint>'] + [
        f'<joint name="j{i}" parent="j{i - 1}"><offset x="1"/><dof axis="z" name="d{i}" {free}/></joint>'
        for i in range(1, n)]
    markers = [f'<marker name="m{i}" joint="j{i}" x="0.5" y="0.2" z="0"/>' for i in range(n)]
    return KinematicModel.from_xml(f'<model name="chain{n}">{"".join(joints + markers)}</model>')


def views(n: int, scale: float) -> Rig:
    """``n`` orthographic views around the y axis, ``scale`` pixels per unit."""
    out = []
    for k in range(n):
        a = np.pi * k / n
        out.append({"name": f"v{k}", "video": 0, "projection": {"type": "affine", "matrix": [
            [scale * np.cos(a), 0, scale * np.sin(a), 100.0], [0, -scale, 0, 100.0]]}})
    return Rig.from_dict({"views": out})


def _best(call, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - t0)
    return best


def measure(j: int, n_views: int, attempt: bool) -> None:
    model, rig = chain(j), views(n_views, 400.0 / j)
    q = np.zeros(len(model.dofs)) + 5.0
    det = Detections.from_views(list(rig.project(model.marker_positions(q))))
    a, r = model.arrays, rig.arrays
    off = np.zeros((n_views, 2))
    image = _kernels.Image.of(det.kernel_points, det.start, off, penalty=5.0, fuse_px=0.0)
    args = (a, r, image)
    start = q + 1.0
    _kernels.posture_error(start, *args)
    loops = max(1, int(2e5 / (j * n_views * j)))
    evaluation = _best(lambda: [_kernels.posture_error(start, *args) for _ in range(loops)]) / loops
    refine_args = (_kernels.Bounds(model.lower, model.upper), a, r, image, 1.0)
    _kernels.refine(start, *refine_args, 1, _kernels.NO_TARGETS)
    step = _best(lambda: _kernels.refine(start, *refine_args, 1, _kernels.NO_TARGETS), 1)
    cost = estimate_fit_cost(model, rig, FitParams(), images=1)
    line = (f"J={j:5d} V={n_views}: evaluation {evaluation * 1e6:10.1f} µs (estimate "
            f"{cost.evaluation_s * 1e6:10.1f}), LM step {step * 1e3:10.1f} ms (estimate "
            f"{cost.lm_step_s * 1e3:10.1f}), attempt bound {cost.image_s:10.3g} s")
    if attempt:
        params = FitParams()
        space = search_space(model, Histograms.uniform(model))
        dofs, error, objective, _, _, _ = fit_image(det, model=model, rig=rig, space=space, params=params,
                                              stream=image_stream(0, 0, 1))
        fit_s = _best(lambda: fit_image(det, model=model, rig=rig, space=space, params=params,
                                        stream=image_stream(0, 0, 1)), 1)
        fit = Candidate(dofs, error, objective)
        geometry = FlipGeometry.of(model, rig)

        def flips() -> None:
            flip_alternatives(fit, det, model=model, rig=rig, geometry=geometry,
                              tolerance_px=params.alternative_tolerance_px, fusion_px=0.0,
                              empty_view_penalty_px=params.empty_view_penalty_px,
                              huber_px=params.anneal.huber_px)
        flips()
        capped = _best(flips, 1)
        ambiguity.MAX_FLIP_REFINES = 2**62  # as before the bound: every flip that passes is refined
        uncapped = _best(flips, 1)
        ambiguity.MAX_FLIP_REFINES = MAX_FLIP_REFINES
        line += (f"; measured: fit {fit_s:.3g} s, flip search {capped:.3g} s "
                 f"(without the bound {uncapped:.3g} s)")
    print(line, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="*", default=[5, 20, 50, 100],
                        help="joints of the models whose whole attempt is timed")
    parser.add_argument("--lm-sizes", type=int, nargs="*", default=[200, 500, 1000],
                        help="joints of the models whose units alone are timed")
    parser.add_argument("--views", type=int, default=2)
    args = parser.parse_args()
    for j in args.sizes:
        measure(j, args.views, attempt=True)
    for j in args.lm_sizes:
        measure(j, args.views, attempt=False)


if __name__ == "__main__":
    main()
