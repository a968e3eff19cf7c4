"""Speed benchmark: fitting the locust benchmark on one core (paper §3.2: 0.4 images/s).

    python bench/speed.py [--samples 668]

Pins the process to one core, renders and detects the locust benchmark
(``core/demo.py``), then times fitting alone with the paper's Table 1
parameters plus refinement (the product's default), and the paper's plain SA
(no refinement, E < ε tested on SA's own best) for comparison. Also prints
the detection rate. Compilation is excluded (a warm-up image runs first).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.anneal import AnnealParams
from core.demo import MARKER_DIAMETER_PX, locust_benchmark
from core.fit import FitParams, fit_sequence
from core.histogram import Histograms

PAPER_FIT_IMAGES_PER_S = 0.4
PAPER_DETECT_IMAGES_PER_S = 8.4
TARGET_FIT = 300.0
TARGET_DETECT = 500.0


def fit_rate(bench, params: FitParams, n: int) -> float:
    dets = bench.detections[:n]
    kwargs = dict(model=bench.model, rig=bench.rig, params=params, seed=1)
    fit_sequence(dets[:1], histograms=Histograms.uniform(bench.model), **kwargs)  # compile
    t0 = time.perf_counter()
    fit_sequence(dets, histograms=Histograms.uniform(bench.model), **kwargs)
    return n / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=668)
    parser.add_argument("--plain-samples", type=int, default=100,
                        help="images timed for the slower plain-SA comparison")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    bench = locust_benchmark(n_samples=args.samples)
    n = len(bench.detections)
    detect_rate = n / bench.detect_seconds
    print(f"one core, locust benchmark ({n} images, 720x576, two views)")
    print(f"detection           {detect_rate:9.1f} images/s  paper {PAPER_DETECT_IMAGES_PER_S}  "
          f"x{detect_rate / PAPER_DETECT_IMAGES_PER_S:.0f}  target {TARGET_DETECT:.0f}: "
          f"{'MET' if detect_rate >= TARGET_DETECT else 'NOT MET'}")
    default = fit_rate(bench, FitParams(fusion_px=MARKER_DIAMETER_PX), n)
    print(f"fit (Table 1 + refinement) {default:9.1f} images/s  paper {PAPER_FIT_IMAGES_PER_S}  "
          f"x{default / PAPER_FIT_IMAGES_PER_S:.0f}  target {TARGET_FIT:.0f}: "
          f"{'MET' if default >= TARGET_FIT else 'NOT MET'}")
    plain = FitParams(anneal=replace(AnnealParams(), polish_every=0), restarts=0)
    rate = fit_rate(bench, plain, min(n, args.plain_samples))
    print(f"fit (plain paper SA, Table 1)  {rate:9.1f} images/s  paper {PAPER_FIT_IMAGES_PER_S}  "
          f"x{rate / PAPER_FIT_IMAGES_PER_S:.0f}")


if __name__ == "__main__":
    main()
