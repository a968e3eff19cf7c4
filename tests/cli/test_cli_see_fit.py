"""`mocap fit --overlay --plots`, `mocap overlay`, `mocap plots` and `mocap detect` end to end."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.app import app
from core.detect import DetectorParams, detect, threshold_level, view_images
from core.examples import LOCUST
from core.model import KinematicModel
from core.overlay import MARK_BGR
from core.results import read_angles_csv
from core.rig import Rig
from core.video import VideoSet

MODEL, RIG = LOCUST / "model.xml", LOCUST / "rig.json"
IMAGES = 8
RUN = CliRunner()


def _invoke(*args):
    return RUN.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("clip")
    result = _invoke("synth", "--model", MODEL, "--rig", RIG, "--out", out, "--samples", IMAGES,
                     "--seed", "5", "--ghosts", "1")
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def fitted(clip, tmp_path_factory) -> Path:
    """A fit with --overlay --plots (few iterations: the overlay draws whatever was fitted)."""
    out = tmp_path_factory.mktemp("fit")
    result = _invoke("fit", clip / "video0.avi", "--model", MODEL, "--rig", RIG, "--out", out,
                     "--marker-diameter-px", "4", "--iterations", "3000", "--overlay", "--plots")
    assert result.exit_code == 0, result.output
    assert f"wrote {out / 'overlay'}" in result.output and f"wrote {out / 'plots'}" in result.output
    return out


def test_fit_overlay_draws_every_image_and_the_fitted_markers_on_their_pixels(fitted):
    manifest = json.loads((fitted / "overlay" / "overlay.json").read_text())
    assert manifest["videos"] == ["video0.avi"] and manifest["contact_sheet"] == "contact_sheet.png"
    video = VideoSet([fitted / "overlay" / "video0.avi"])
    assert video.frames == IMAGES
    table = read_angles_csv(fitted / "angles.csv")
    order = np.argsort(-table.errors, kind="stable")
    assert [i["sample"] for i in manifest["images"]] == order.tolist()  # all 8: worst first
    model, rig = KinematicModel.from_xml(MODEL), Rig.from_json(RIG)
    for item in manifest["images"]:
        image = cv2.imread(str(fitted / "overlay" / item["file"]))
        projected = rig.project(model.marker_positions(table.dofs[item["sample"]]))
        colour = list(MARK_BGR["ambiguous" if item["alternative_deg"] is not None else item["status"]])
        for u, v in projected.reshape(-1, 2):
            if v >= 20:  # below the line of text at the top
                assert image[int(v), int(u)].tolist() == colour
    sheet = cv2.imread(str(fitted / "overlay" / "contact_sheet.png"))
    assert sheet is not None and sheet.shape[1] == 4 * 320


def test_fit_plots_are_written(fitted):
    for name in ("angles.png", "angles.svg", "histograms.png", "histograms.svg"):
        assert (fitted / "plots" / name).stat().st_size > 1000
    assert cv2.imread(str(fitted / "plots" / "angles.png")) is not None


def test_overlay_command_redraws_the_same_images_from_the_results(clip, fitted, tmp_path):
    results = tmp_path / "results"
    shutil.copytree(fitted, results, ignore=shutil.ignore_patterns("overlay", "plots"))
    result = _invoke("overlay", results, clip / "video0.avi", "--model", MODEL, "--rig", RIG,
                     "--worst", "3")
    assert result.exit_code == 0, result.output
    manifest = json.loads((results / "overlay" / "overlay.json").read_text())
    first = json.loads((fitted / "overlay" / "overlay.json").read_text())
    assert manifest["images"] == first["images"][:3]
    for item in manifest["images"]:
        assert (results / "overlay" / item["file"]).read_bytes() == (
            fitted / "overlay" / item["file"]).read_bytes()
    shutil.copy(MODEL, results / "model.xml")  # as in a job's archive
    result = _invoke("plots", results)
    assert result.exit_code == 0, result.output
    assert (results / "plots" / "angles.svg").read_bytes() == (fitted / "plots" / "angles.svg").read_bytes()


@pytest.mark.parametrize(("case", "match"), [
    ("no_model", "has no model.xml: give it with --model"),
    ("other_video", "angles.csv has 8 images, the videos give 5"),
    ("two_videos", "expects 1 video"),
    ("not_results", "is not a directory of results"),
    ("bad_report", "is not a report.json of mocap fit"),
])
def test_overlay_bad_input_exits_2_with_one_line(clip, fitted, tmp_path, case, match):
    results, videos, extra = fitted, [clip / "video0.avi"], ["--model", MODEL, "--rig", RIG]
    if case == "no_model":
        extra = ["--rig", RIG]
    elif case == "other_video":
        short = _invoke("synth", "--model", MODEL, "--rig", RIG, "--out", tmp_path, "--samples", "5")
        assert short.exit_code == 0
        videos = [tmp_path / "video0.avi"]
    elif case == "two_videos":
        videos = videos * 2
    elif case == "bad_report":
        results = tmp_path / "results"
        shutil.copytree(fitted, results, ignore=shutil.ignore_patterns("overlay", "plots"))
        (results / "report.json").write_text("[1, 2")
    else:
        results = tmp_path / "nothing"
        extra = []
    result = _invoke("overlay", results, *videos, *extra)
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mocap: error:") and match in lines[0], result.output


@pytest.mark.parametrize("threshold", ["90", "auto"])
def test_detect_preview_prints_core_detects_counts_and_thresholds(clip, tmp_path, threshold):
    """Each frame's line gives every view's count and the threshold it was detected at: the
    fixed level, or the one 'auto' picked for that view (core.detect.threshold_level)."""
    result = _invoke("detect", clip / "video0.avi", "--rig", RIG, "--frames", "6,0,3",
                     "--out", tmp_path, "--threshold", threshold)
    assert result.exit_code == 0, result.output
    rig = Rig.from_json(RIG)
    params = DetectorParams(threshold=threshold if threshold == "auto" else float(threshold))
    written = json.loads((tmp_path / "counts.json").read_text())
    lines = result.output.splitlines()
    for line, index in zip(lines, (0, 3, 6), strict=False):
        (frames,) = VideoSet([clip / "video0.avi"]).read(index, index + 1)
        expected = detect(frames, rig=rig, params=params).counts
        levels = [threshold_level(v, params) for v in view_images(frames, rig, params)]
        assert (levels[0] == 90.0) if threshold == "90" else (30.0 < levels[0] < 200.0)
        assert line == (f"frame {index}: side {expected[0]} (threshold {levels[0]:g}), "
                        f"top {expected[1]} (threshold {levels[1]:g})")
        assert written["counts"][str(index)] == {"side": int(expected[0]), "top": int(expected[1])}
        assert written["thresholds"][str(index)] == {"side": levels[0], "top": levels[1]}
        assert cv2.imread(str(tmp_path / f"frame_{index:06d}_video0.png")) is not None


@pytest.mark.parametrize(("frames", "match"), [("0,99", "past the videos' 8 frames"),
                                               ("a,b", "--frames must be"), ("-1", "--frames must")])
def test_detect_bad_frames_exit_2(clip, tmp_path, frames, match):
    result = _invoke("detect", clip / "video0.avi", "--rig", RIG, "--frames", frames, "--out", tmp_path)
    assert result.exit_code == 2 and match in result.output, result.output


def test_overlay_shows_every_ambiguous_image_of_angles_csv(clip, fitted, tmp_path):
    """angles.csv's optional alternative_deg column (FORMATS §3) marks images ambiguous."""
    results = tmp_path / "results"
    shutil.copytree(fitted, results, ignore=shutil.ignore_patterns("overlay", "plots"))
    table = read_angles_csv(fitted / "angles.csv")
    best = int(np.argmin(table.errors))  # never among the worst 2
    with (fitted / "angles.csv").open(newline="") as fh:
        rows = list(csv.reader(fh))
    column = rows[0].index("alternative_deg")
    for i, row in enumerate(rows[1:]):
        row[column] = "35.5" if i == best else ""
    with (results / "angles.csv").open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    result = _invoke("overlay", results, clip / "video0.avi", "--model", MODEL, "--rig", RIG,
                     "--worst", "2")
    assert result.exit_code == 0, result.output
    images = json.loads((results / "overlay" / "overlay.json").read_text())["images"]
    assert [i["sample"] for i in images] == [*np.argsort(-table.errors, kind="stable")[:2].tolist(), best]
    assert images[-1]["alternative_deg"] == 35.5 and images[0]["alternative_deg"] is None
    image = cv2.imread(str(results / "overlay" / images[-1]["file"]))
    u, v = Rig.from_json(RIG).project(KinematicModel.from_xml(MODEL).marker_positions(table.dofs[best]))[0, 1]
    assert image[int(v), int(u)].tolist() == list(MARK_BGR["ambiguous"])


def test_deinterlaced_overlay_draws_every_field(tmp_path):
    clip = tmp_path / "clip"
    assert _invoke("synth", "--model", MODEL, "--rig", RIG, "--out", clip, "--samples", "6",
                   "--interlaced", "--seed", "2").exit_code == 0
    result = _invoke("fit", clip / "video0.avi", "--model", MODEL, "--rig", RIG, "--out", tmp_path / "out",
                     "--marker-diameter-px", "4", "--iterations", "3000", "--deinterlace", "--overlay")
    assert result.exit_code == 0, result.output
    assert VideoSet([tmp_path / "out" / "overlay" / "video0.avi"]).frames == 6  # 3 frames, 2 fields
    images = json.loads((tmp_path / "out" / "overlay" / "overlay.json").read_text())["images"]
    assert sorted((i["frame"], i["field"]) for i in images) == [
        (f, p) for f in range(3) for p in ("even", "odd")]
