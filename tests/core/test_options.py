"""core.options: one FitOptions with its bounds, and build_fit, the one way from options to a fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.anneal import AnnealParams
from core.bounds import Bounds, OptionError, bounds_of
from core.detect import DetectorParams
from core.error import fusion_distance
from core.examples import LOCUST
from core.fit import FitParams
from core.histogram import Histograms
from core.model import KinematicModel
from core.options import FitOptions, build_fit
from core.pipeline import VideoSource, estimate_marker_diameter
from core.rig import Rig
from core.synth import natural_movements, render_frames, write_video


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """12 images of the locust example with 4 px markers."""
    model, rig = KinematicModel.from_xml(LOCUST / "model.xml"), Rig.from_json(LOCUST / "rig.json")
    rng = np.random.default_rng(5)
    truth = natural_movements(model, rig, 12, rng=rng, n_sequences=1)
    path = tmp_path_factory.mktemp("clip") / "video0.avi"
    write_video(path, render_frames(model, rig, truth, rng=rng, marker_diameter_px=4.0), fps=50.0)
    return model, rig, path


def test_every_field_is_an_option_with_help_or_the_detector():
    names = [f.name for f in dataclasses.fields(FitOptions)]
    assert [n for n in names if n not in bounds_of(FitOptions)] == ["detector"]
    every = [*bounds_of(FitOptions).values(), *bounds_of(DetectorParams).values()]
    assert all(len(b.help) > 15 for b in every)
    assert list(bounds_of(DetectorParams)) == [f.name for f in dataclasses.fields(DetectorParams)]


def test_the_resolved_parameters_share_the_options_defaults():
    """FitParams' threshold, attempts and SA schedule are FitOptions' defaults: they cannot drift."""
    options = FitOptions()
    params = options.fit_params(0.0)
    assert params == FitParams()  # 0 px markers: the paper's plain Eq. 5, FitParams' own default
    assert (options.error_threshold_px, options.max_attempts, options.iterations) == (
        FitParams().error_threshold_px, FitParams().max_attempts, AnnealParams().n_end)
    assert options.marker_diameter_px == "auto"  # what mocap fit and the API minimise by default
    assert options.fit_params(4.0).fusion_px == fusion_distance(4.0)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"marker_diameter_px": -3}, "marker_diameter_px must be 'auto' or a number in 0..1000, got -3"),
    ({"marker_diameter_px": "big"}, "marker_diameter_px must be"),
    ({"marker_diameter_px": float("inf")}, "marker_diameter_px"),
    ({"error_threshold_px": 0}, "error_threshold_px must be a number > 0"),
    ({"error_threshold_px": float("nan")}, "error_threshold_px"),
    ({"max_attempts": 101}, "max_attempts must be an integer in 1..100"),
    ({"max_attempts": 2.0}, "max_attempts"),
    ({"iterations": 0}, "iterations must be an integer in 1..10000000"),
    ({"iterations": 10**400}, "iterations must be an integer in 1..10000000"),
    ({"seed": -1}, "seed must be an integer >= 0 and < 9223372036854775808"),
    ({"chunk_size": 0}, "chunk_size must be an integer in 1..1000000 (or none)"),
    ({"field_order": "odd"}, "field_order must be one of even-first, odd-first"),
    ({"deinterlace": 1}, "deinterlace must be true or false"),
    ({"prior_weight": 0}, "prior_weight must be a number > 0 and <= 1e+300"),
    ({"root_marker": ""}, "root_marker"),
    ({"root_marker": "M0", "root_start": ((1.0, float("nan")),)}, "root_start"),
    ({"root_marker": "M0", "root_max_jump_px": -1}, "root_max_jump_px"),
    ({"root_start": ((1.0, 2.0),)}, "root_start needs root_marker"),
    ({"detector": {"blur": 3}}, "detector must be DetectorParams"),
])
def test_bad_options_raise_an_error_naming_the_option(kwargs, message):
    with pytest.raises(OptionError) as caught:
        FitOptions(**kwargs)
    assert message in str(caught.value)
    assert str(caught.value).startswith(caught.value.name)


def test_bounds_in_words():
    assert Bounds("h", kind=int, ge=0, le=20).describe() == "an integer in 0..20"
    assert Bounds("h", gt=0, optional=True).describe() == "a number > 0 (or none)"
    assert Bounds("h", ge=0, le=255, words=("otsu",)).describe() == "'otsu' or a number in 0..255"
    Bounds("h", ge=0, le=255, words=("otsu",)).check("threshold", "otsu")
    with pytest.raises(OptionError, match=r"threshold must be 'otsu' or a number in 0\.\.255, got True"):
        Bounds("h", ge=0, le=255, words=("otsu",)).check("threshold", True)


def test_build_fit_resolves_auto_from_the_first_images_and_starts_from_the_uniform_prior(clip):
    model, rig, video = clip
    fit = build_fit(FitOptions(prior_weight=50.0, iterations=7000, seed=3, chunk_size=4), model, rig, [video])
    diameter = estimate_marker_diameter(VideoSource((video,), rig))
    assert 3.5 < diameter < 4.5
    assert fit.job.params == FitOptions(iterations=7000).fit_params(diameter)
    assert fit.job.params.anneal == AnnealParams().with_iterations(7000)
    assert (fit.job.seed, fit.job.chunk_size, fit.job.root) == (3, 4, None)
    uniform = Histograms.uniform(model, prior_weight=50.0)
    np.testing.assert_array_equal(fit.start.counts, uniform.counts)
    given = build_fit(FitOptions(marker_diameter_px=0), model, rig, [video], start=uniform.copy())
    assert given.job.params.fusion_px == 0.0
    np.testing.assert_array_equal(given.start.counts, uniform.counts)


def test_build_fit_passes_detector_fields_and_root_tracking(clip):
    model, rig, video = clip
    options = FitOptions(deinterlace=True, field_order="odd-first", marker_diameter_px=4.0,
                         detector=DetectorParams(threshold="otsu", blur=3), root_marker="M0",
                         root_start=((240, 184), (240, 438)), root_max_jump_px=9.0)
    job = build_fit(options, model, rig, [video]).job
    assert (job.source.deinterlace, job.source.field_order, job.source.detector) == (
        True, "odd-first", options.detector)
    assert (job.root.marker, job.root.max_jump_px) == ("M0", 9.0)
    assert job.root.start == ((240.0, 184.0), (240.0, 438.0))


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"root_marker": "M3"}, "root marker 'M3' must sit at the origin of the root joint"),
    ({"root_marker": "nope"}, "root marker 'nope' is not a marker"),
    ({"root_marker": "M0", "root_start": ((1.0, 2.0),)}, "root_start has 1 (u, v) pair(s) for a rig of 2"),
])
def test_root_tracking_is_checked_against_model_and_rig_before_any_work(clip, kwargs, message):
    model, rig, video = clip
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        build_fit(FitOptions(**kwargs), model, rig, [video])


def test_build_fit_wants_one_video_per_video_of_the_rig(clip):
    model, rig, video = clip
    with pytest.raises(ValueError, match="the rig expects 1 video"):
        build_fit(FitOptions(), model, rig, [video, video])
