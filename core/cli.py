"""The ``mocap`` command line.

Errors a user can make (bad files, bad options) end with exit code 2 and one
line on stderr saying what is wrong.
"""

from __future__ import annotations

import time

import numpy as np
import typer

from core.demo import MARKER_DIAMETER_PX, locust_benchmark
from core.fit import FitParams, Status, fit_sequence
from core.histogram import Histograms

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__.splitlines()[0])


@app.callback()
def main() -> None:
    """Model-based motion capture by Simulated Annealing (Zakotnik et al. 2004)."""


@app.command()
def demo(
    samples: int = typer.Option(200, min=1, max=5000, help="images to render and fit"),
    seed: int = typer.Option(2004, help="seed of the movement, the rendering and the fit"),
) -> None:
    """Render the locust hind-leg example, detect its markers, fit it and print the accuracy."""
    t0 = time.perf_counter()
    bench = locust_benchmark(seed, samples)
    print(f"rendered and detected {samples} images of the locust hind leg "
          f"(two views, 4 px markers) in {time.perf_counter() - t0:.1f} s")
    t0 = time.perf_counter()
    result = fit_sequence(bench.detections, model=bench.model, rig=bench.rig,
                          histograms=Histograms.uniform(bench.model),
                          params=FitParams(fusion_px=MARKER_DIAMETER_PX), seed=seed)
    seconds = time.perf_counter() - t0
    fitted = np.array([f.dofs for f in result.fits])
    rmse = np.sqrt(np.nanmean((fitted - bench.truth) ** 2, axis=0))
    errors = np.array([f.error for f in result.fits])
    print(f"fitted {samples} images in {seconds:.1f} s ({samples / seconds:.0f} images/s, "
          "one process, compilation included on a first run)")
    print("RMSE against the truth (degrees): " + ", ".join(
        f"{name} {value:.3f}" for name, value in zip(bench.model.dof_names, rmse, strict=True)))
    print(f"mean view error {np.nanmean(errors):.3f} px (Eq. 5, 8 markers); "
          f"{sum(f.status is not Status.OK for f in result.fits)} images not ok")
