"""`mocap fit`'s and `mocap detect`'s options and the API's JobOptions are generated from
core.options.FitOptions: every option in all three, with one default."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import typer.main
from typer.core import TyperGroup, TyperOption
from typer.testing import CliRunner

from cli.app import app
from cli.options import markdown_table
from core.bounds import bounds_of
from core.detect import DetectorParams
from core.examples import LOCUST
from core.options import FitOptions
from service.schemas import DetectorOptions, JobOptions, fit_options

FIT_FIELDS = {name: f.default for f in dataclasses.fields(FitOptions)
              if (name := f.name) != "detector"}
DETECTOR_FIELDS = {f.name: f.default for f in dataclasses.fields(DetectorParams)}


def _options(command: str) -> dict[str, TyperOption]:
    group = typer.main.get_command(app)
    assert isinstance(group, TyperGroup)
    return {p.name: p for p in group.commands[command].params if isinstance(p, TyperOption)}


def _as_typed(value: object) -> object:
    """A command-line default as the option's value: numbers and words are read from text."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


@pytest.mark.parametrize(("name", "default"), [*FIT_FIELDS.items(), *DETECTOR_FIELDS.items()])
def test_every_option_is_one_of_mocap_fit_with_the_same_default(name, default):
    option = _options("fit")[name]
    assert _as_typed(option.default) == default
    assert option.opts == ["--" + name.replace("_", "-")]
    bounds = {**bounds_of(FitOptions), **bounds_of(DetectorParams)}[name]
    assert bounds.help in option.help


@pytest.mark.parametrize(("name", "default"), FIT_FIELDS.items())
def test_every_option_is_a_field_of_job_options_with_the_same_default(name, default):
    field = JobOptions.model_fields[name]
    assert field.default == default
    assert field.description == bounds_of(FitOptions)[name].help


@pytest.mark.parametrize(("name", "default"), DETECTOR_FIELDS.items())
def test_every_detector_option_is_one_of_mocap_detect_and_the_api(name, default):
    assert _as_typed(_options("detect")[name].default) == default
    assert DetectorOptions.model_fields[name].default == default


def test_job_options_defaults_are_fit_options_defaults():
    assert fit_options(JobOptions()) == FitOptions()


def test_job_options_of_jobs_stored_before_prior_weight_and_root_tracking_still_validate():
    stored = {"deinterlace": False, "field_order": "even-first", "error_threshold_px": 1.25,
              "max_attempts": 5, "iterations": 35000, "seed": 0, "chunk_size": None,
              "marker_diameter_px": "auto",
              "histogram_version": None, "detector": {"threshold": 100.0, "channel": "grey", "blur": 0,
                                                      "erode": 0, "dilate": 0, "min_area": 2,
                                                      "max_area": 2000},
              "overlay": False, "plots": False}
    expected = FitOptions(detector=DetectorParams(threshold=100.0))
    assert fit_options(JobOptions.model_validate(stored)) == expected


def test_root_start_in_json_is_a_list_of_pairs():
    options = JobOptions.model_validate({"root_marker": "M0", "root_start": [[240, 184], [240.5, 438]]})
    assert fit_options(options).root_start == ((240.0, 184.0), (240.5, 438.0))


@pytest.mark.parametrize(("args", "message"), [
    (["--blur", "4"], "--blur must be 0 (none) or an odd kernel size, got 4"),
    (["--threshold", "bright"], "--threshold must be 'otsu', 'auto' or a number in 0..255, got 'bright'"),
    (["--seed", "-1"], "--seed must be an integer >= 0"),
    (["--field-order", "odd"], "--field-order must be one of even-first, odd-first"),
    (["--root-marker", "M0", "--root-start", "1,2;3"], "--root-start must be 'u,v;u,v'"),
    (["--root-start", "1,2;3,4"], "--root-start needs root_marker"),
    (["--prior-weight", "0"], "--prior-weight must be a number > 0"),
])
def test_an_option_out_of_its_bounds_is_one_line_naming_the_flag(tmp_path, args, message):
    video = tmp_path / "v.avi"
    video.write_bytes(b"")
    result = CliRunner().invoke(app, ["fit", str(video), "--model", str(LOCUST / "model.xml"), "--rig",
                                      str(LOCUST / "rig.json"), "--out", str(tmp_path / "o"), *args])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"mocap: error: {message}"), result.output


def test_the_options_table_of_the_docs_is_the_generated_one():
    text = (Path(__file__).parents[2] / "docs" / "OPTIONS.md").read_text()
    table = text.split("<!-- generated: markdown_table() -->\n")[1]
    table = table.split("<!-- end of generated table -->")[0]
    assert table == markdown_table()
