"""The options of a fit as a user gives them, and the one function that builds the fit from them.

:class:`FitOptions` is what decides a result besides model, rig, videos and starting
histograms, with each option's default, bounds and help stated once (``core.bounds``):
``mocap fit``'s options (``cli.app``) and the API's ``JobOptions`` (``service.schemas``)
are generated from it, and :func:`build_fit` is how both turn it into a
``core.pipeline.FitJob``. From Python, fit as ``mocap fit`` does::

    from core.options import FitOptions, build_fit
    from core.pipeline import run_fit, write_outputs

    fit = build_fit(FitOptions(seed=1), model, rig, [video])
    outcome = run_fit(fit.job, fit.start)

``core.fit.FitParams`` are the resolved internal parameters (marker fusion as a distance,
SA's schedule); its own defaults are the paper's plain Eq. 5, not what ``mocap fit`` minimises.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from core.anneal import AnnealParams
from core.bounds import OptionError, check_options, option
from core.detect import DetectorParams
from core.error import fusion_distance
from core.fit import FitParams
from core.histogram import MAX_COUNT, Histograms
from core.model import KinematicModel
from core.pipeline import FitJob, VideoSource, estimate_marker_diameter
from core.rig import MAX_VIEWS, Rig
from core.track import RootTracking, root_reference

__all__ = ["Fit", "FitOptions", "build_fit"]

MAX_ITERATIONS = 10_000_000
MAX_CHUNK_SIZE = 1_000_000
MAX_MARKER_DIAMETER_PX = 1000
MAX_MARKER_NAME_CHARS = 200
MAX_JUMP_PX = 1e6


@dataclass(frozen=True)
class FitOptions:
    """Every option of a fit that decides its result (as ``mocap fit`` and the API take them).

    Validated on creation: :class:`core.bounds.OptionError` (a ValueError) names the option.
    ``detector`` holds the marker detection's options (``core.detect.DetectorParams``).
    """

    deinterlace: bool = option(False, kind=bool, help="fit both fields of every frame (50 images/s "
                               "from PAL's 25 frames/s)")
    field_order: str = option("even-first", kind=str, words=("even-first", "odd-first"),
                              help="which field comes first in time (DV is odd-first)")
    error_threshold_px: float = option(
        FitParams.error_threshold_px, gt=0,
        help="Eq. 5 error per compared marker projection (markers x views with any detection) above "
             "which an image is re-analysed and reported over_threshold; the paper's 10 px over "
             "4 markers x 2 views is 1.25")
    max_attempts: int = option(FitParams.max_attempts, kind=int, ge=1, le=100,
                               help="fits per image at most, the first included")
    iterations: int = option(AnnealParams.n_end, kind=int, ge=1, le=MAX_ITERATIONS,
                             help="SA iterations N_end (N_l, N_tau scale along)")
    seed: int = option(0, kind=int, ge=0, lt=2**63, help="random seed: same seed, same result")
    chunk_size: int | None = option(None, kind=int, ge=1, le=MAX_CHUNK_SIZE, optional=True,
                                    help="images per chunk at most, chunks of even sizes (none: one chunk, "
                                         "or 4 per process of `mocap fit --jobs`, or the server's default)")
    marker_diameter_px: float | str = option(
        "auto", ge=0, le=MAX_MARKER_DIAMETER_PX, words=("auto",),
        help="markers' diameter in pixels, closer markers may image as one blob: 'auto' (from the "
             "blobs of the first images) or a number (0: the paper's plain Eq. 5)")
    detector: DetectorParams = field(default_factory=DetectorParams)
    prior_weight: float = option(100.0, gt=0, le=MAX_COUNT,
                                 help="counts of the uniform prior histograms, when the fit starts "
                                      "from them")
    root_marker: str | None = option(None, kind=str, optional=True, max_length=MAX_MARKER_NAME_CHARS,
                                     help="track this marker (at the root's origin) to move the root")
    root_start: tuple[tuple[float, float], ...] | None = option(
        None, kind=tuple, optional=True, max_length=MAX_VIEWS,
        help="the root marker's (u, v) in every view of the first image (none: where the rig "
             "projects it)")
    root_max_jump_px: float = option(20.0, gt=0, le=MAX_JUMP_PX,
                                     help="largest move of the root marker per image, pixels")

    def __post_init__(self) -> None:
        check_options(self)
        if not isinstance(self.detector, DetectorParams):
            raise OptionError("detector", f"must be DetectorParams, got {self.detector!r}")
        if self.root_start is not None and self.root_marker is None:
            raise OptionError("root_start", "needs root_marker (the marker it is the start of)")

    def fit_params(self, marker_diameter_px: float) -> FitParams:
        """The resolved parameters for markers of this diameter (``marker_diameter_px`` resolved)."""
        return FitParams(anneal=AnnealParams().with_iterations(self.iterations),
                         error_threshold_px=self.error_threshold_px, max_attempts=self.max_attempts,
                         fusion_px=fusion_distance(marker_diameter_px))

    def root_tracking(self, model: KinematicModel, rig: Rig) -> RootTracking | None:
        """Root tracking of these options, checked against model and rig (ValueError)."""
        if self.root_marker is None:
            return None
        root_reference(model, rig, self.root_marker)  # a marker of the model, at the root's origin
        start = None if self.root_start is None else tuple((float(u), float(v)) for u, v in self.root_start)
        if start is not None and len(start) != len(rig.views):
            raise OptionError("root_start", f"has {len(start)} (u, v) pair(s) for a rig of "
                                            f"{len(rig.views)} view(s)")
        return RootTracking(self.root_marker, start, self.root_max_jump_px)

    def uniform_prior(self, model: KinematicModel) -> Histograms:
        """The uniform prior of ``model`` worth ``prior_weight`` counts (a fit's default start)."""
        return Histograms.uniform(model, prior_weight=self.prior_weight)


@dataclass(frozen=True)
class Fit:
    """A fit ready to run (``core.pipeline.run_fit(fit.job, fit.start)``)."""

    job: FitJob
    start: Histograms


def build_fit(options: FitOptions, model: KinematicModel, rig: Rig, videos: Sequence[Path],
              start: Histograms | None = None) -> Fit:
    """The fit of ``videos`` (one per video of ``rig``) with ``options``.

    marker_diameter_px 'auto' is estimated from the detections of the first images
    (``core.pipeline.estimate_marker_diameter``; 0, the plain Eq. 5, if none has any); the
    estimate is deterministic, so every process building the same fit gets the same one.
    The fit's source restores the blobs its views' edges cut to markers of that diameter
    (``VideoSource.marker_px``).
    start : the starting histograms; None: uniform, worth ``options.prior_weight`` counts.
    """
    if len(videos) != rig.n_videos:
        raise ValueError(f"the rig expects {rig.n_videos} video(s), got {len(videos)}")
    source = VideoSource(tuple(Path(v) for v in videos), rig, options.detector, options.deinterlace,
                         options.field_order)
    root = options.root_tracking(model, rig)
    diameter = options.marker_diameter_px
    if diameter == "auto":
        diameter = estimate_marker_diameter(source) or 0.0
    source = source.restoring(float(diameter))
    job = FitJob(source, model, options.fit_params(float(diameter)), options.seed, options.chunk_size, root)
    return Fit(job, start if start is not None else options.uniform_prior(model))

