"""`mocap synth` and `mocap fit` end to end: files in, FORMATS files out, clear errors."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.app import app
from core.error import fusion_distance
from core.examples import LOCUST
from core.histogram import Histograms
from core.model import KinematicModel
from core.pipeline import VideoSource, estimate_marker_diameter
from core.results import read_angles_csv
from core.rig import Rig
from core.synth import natural_movements, read_truth_csv, render_frames, write_video

RUN = CliRunner()


def _invoke(*args: str):
    return RUN.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("clip")
    result = _invoke("synth", "--model", LOCUST / "model.xml", "--rig", LOCUST / "rig.json",
                     "--out", out, "--samples", "40", "--seed", "3")
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def interlaced_clip(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("interlaced")
    result = _invoke("synth", "--model", LOCUST / "model.xml", "--rig", LOCUST / "rig.json",
                     "--out", out, "--samples", "24", "--seed", "4", "--interlaced")
    assert result.exit_code == 0, result.output
    return out


def _chain_xml(n: int) -> str:
    """A chain of ``n`` joints, one DOF and one marker each (within the file limits)."""
    joints = ['<joint name="j0"><dof axis="z" name="d0" min="-30" max="30"/></joint>'] + [
        f'<joint name="j{i}" parent="j{i - 1}"><offset x="1"/><dof axis="z" name="d{i}" min="-30" '
        'max="30"/></joint>' for i in range(1, n)]
    markers = [f'<marker name="m{i}" joint="j{i}"/>' for i in range(n)]
    return f'<model name="chain">{"".join(joints + markers)}</model>'


def _fit(clip: Path, out: Path, *extra: str):
    return _invoke("fit", clip / "video0.avi", "--model", LOCUST / "model.xml",
                   "--rig", LOCUST / "rig.json", "--out", out, "--marker-diameter-px", "4", *extra)


def test_fit_writes_formats_files_and_matches_the_truth(clip, tmp_path):
    result = _fit(clip, tmp_path / "out", "--seed", "1")
    assert result.exit_code == 0, result.output
    table = read_angles_csv(tmp_path / "out" / "angles.csv")
    names, truth = read_truth_csv(clip / "truth.csv")
    assert table.dof_names == names
    assert table.samples.tolist() == list(range(40)) and table.frames.tolist() == list(range(40))
    assert set(table.fields) == {""}
    np.testing.assert_allclose(table.times, np.arange(40) / 50.0)
    rmse = np.sqrt(np.mean((table.dofs - truth) ** 2, axis=0))
    assert np.all(rmse < 0.5), rmse
    assert all(s.value == "ok" for s in table.statuses)
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    hist = Histograms.from_xml(tmp_path / "out" / "histograms.xml", model)
    assert hist.counts[0] == 100 + 40
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["images"] == 40 and report["status"]["ok"] == 40
    assert report["detections_per_view"]["side"]["min"] >= 3
    assert report["settings"]["seed"] == 1
    assert report["undetermined_dofs"] == [] and "warning" not in result.stderr


def test_fit_warns_once_about_a_dof_the_markers_cannot_determine_and_goes_on(clip, tmp_path):
    """The locust leg with a claw joint that turns and carries no marker: one warning line
    naming the file, the DOF and the fix, a normal fit, and report.json listing the DOF; once
    fitted, the advice on ambiguous images names it too (every image, claw_z the farthest)."""
    xml = (LOCUST / "model.xml").read_text().replace(
        "  <marker", '  <joint name="claw" parent="tarsus"><offset x="3"/>'
        '<dof axis="z" name="claw_z" min="-30" max="30"/></joint>\n  <marker', 1)
    model = tmp_path / "claw.xml"
    model.write_text(xml)
    result = _invoke("fit", clip / "video0.avi", "--model", model, "--rig", LOCUST / "rig.json",
                     "--out", tmp_path / "out", "--marker-diameter-px", "4")
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    assert warnings[0] == f"mocap: warning: {model}: claw_z moves no marker: add a marker to segment claw"
    assert warnings[1:] == ["mocap: warning: 40 of 40 images are ambiguous (another posture fits about "
                            "as well: alternative_deg), most often in claw_z (40): a marker on their "
                            "segments, or a camera that sees them from another side, would determine "
                            "them; an overlay marks the ambiguous images (--overlay; "
                            "docs/SEEING_THE_FIT.md)"], result.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["undetermined_dofs"] == ["claw_z"]
    assert report["ambiguous"] == report["images"] == 40  # claw_z can be anything: every image
    assert report["ambiguous_dofs"] == {"claw_z": 40}


def test_fit_warns_about_a_view_whose_background_is_brighter_than_the_threshold(tmp_path):
    """The locust filmed on a lit background (grey 150, markers 255): at threshold 100 the
    whole view is one region, larger than the largest marker, and nothing is detected.
    The fit goes on (every image ``no_detections``) and one line per view names the view and
    the settings to check; ``--threshold 200`` and the default 'auto' find the markers, and
    no warning is given."""
    model, rig = KinematicModel.from_xml(LOCUST / "model.xml"), Rig.from_json(LOCUST / "rig.json")
    truth = natural_movements(model, rig, 6, rng=np.random.default_rng(0))
    write_video(tmp_path / "lit.avi", render_frames(model, rig, truth, rng=np.random.default_rng(1),
                                                    background=150, marker_level=255), fps=50.0)
    lit = _invoke("fit", tmp_path / "lit.avi", "--model", LOCUST / "model.xml", "--rig", LOCUST / "rig.json",
                  "--out", tmp_path / "lit", "--marker-diameter-px", "4", "--threshold", "100")
    assert lit.exit_code == 0, lit.output
    warnings = [line for line in lit.stderr.splitlines() if "warning" in line]
    assert [w.split(" has ")[0] for w in warnings] == ["mocap: warning: view 'side'",
                                                       "mocap: warning: view 'top'"], lit.stderr
    assert all("--threshold (100.0;" in w and "--max-area (2000)" in w for w in warnings)
    for threshold in (("--threshold", "200"), ()):
        out = tmp_path / (threshold[-1] if threshold else "default")
        set_right = _invoke("fit", tmp_path / "lit.avi", "--model", LOCUST / "model.xml", "--rig",
                            LOCUST / "rig.json", "--out", out, "--marker-diameter-px", "4", *threshold)
        assert set_right.exit_code == 0 and "warning" not in set_right.stderr, set_right.output
        report = json.loads((out / "report.json").read_text())
        assert report["status"]["no_detections"] == 0


def test_fit_warns_when_most_images_are_over_the_threshold(clip, tmp_path):
    """A rig whose top view is 8 px off (SEEING_THE_FIT's calibration mistake): every image
    over the threshold, and one line says so and what to check; the right rig, none."""
    data = json.loads((LOCUST / "rig.json").read_text())
    data["views"][1]["projection"]["matrix"][0][3] += 8
    shifted = tmp_path / "rig_shifted.json"
    shifted.write_text(json.dumps(data))
    result = _invoke("fit", clip / "video0.avi", "--model", LOCUST / "model.xml", "--rig", shifted,
                     "--out", tmp_path / "shifted", "--marker-diameter-px", "4")
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 1 and warnings[0].startswith(
        "mocap: warning: 40 of 40 images are over the threshold (median "), result.stderr
    assert "threshold 1.25): check the model's segment lengths" in warnings[0]
    assert warnings[0].endswith("(--overlay; docs/SEEING_THE_FIT.md)")
    report = json.loads((tmp_path / "shifted" / "report.json").read_text())
    assert len(report["advice"]) == 1 and report["advice"][0] in warnings[0]
    right = _invoke("fit", clip / "video0.avi", "--model", LOCUST / "model.xml", "--rig",
                    LOCUST / "rig.json", "--out", tmp_path / "right", "--marker-diameter-px", "4")
    assert right.exit_code == 0 and "warning" not in right.stderr, right.output
    assert json.loads((tmp_path / "right" / "report.json").read_text())["advice"] == []


def test_two_jobs_give_the_same_result_as_one_with_the_same_chunks(clip, tmp_path):
    one = _fit(clip, tmp_path / "one", "--chunk-size", "20", "--jobs", "1")
    two = _fit(clip, tmp_path / "two", "--chunk-size", "20", "--jobs", "2")
    assert one.exit_code == 0 and two.exit_code == 0, one.output + two.output
    assert gc.get_freeze_count() == 0  # the heap frozen for the forks is collected again
    a = read_angles_csv(tmp_path / "one" / "angles.csv")
    b = read_angles_csv(tmp_path / "two" / "angles.csv")
    np.testing.assert_array_equal(a.dofs, b.dofs)
    assert (tmp_path / "one" / "histograms.xml").read_text() == (
        tmp_path / "two" / "histograms.xml").read_text()


def test_deinterlaced_fit_reports_fields(interlaced_clip, tmp_path):
    result = _fit(interlaced_clip, tmp_path / "out", "--deinterlace")
    assert result.exit_code == 0, result.output
    table = read_angles_csv(tmp_path / "out" / "angles.csv")
    _, truth = read_truth_csv(interlaced_clip / "truth.csv")
    assert len(table.samples) == 24
    assert table.fields[:4] == ["even", "odd", "even", "odd"]
    assert table.frames[:4].tolist() == [0, 0, 1, 1]
    np.testing.assert_allclose(table.times[:3], [0.0, 0.01, 0.02])
    assert np.median(np.abs(table.dofs - truth)) < 0.5


@pytest.mark.parametrize(("name", "deinterlace"), [("clip", False), ("interlaced_clip", True)])
def test_marker_diameter_is_estimated_in_frame_pixels_by_default(request, name, deinterlace, tmp_path):
    """Rendered 4 px markers: the default 'auto' finds 3.5-4.5 px (fields: areas in frame pixels)
    and fits with the fusion distance of that diameter."""
    clip = request.getfixturevalue(name)
    source = VideoSource((clip / "video0.avi",), Rig.from_json(LOCUST / "rig.json"),
                         deinterlace=deinterlace)
    diameter = estimate_marker_diameter(source)
    assert 3.5 < diameter < 4.5
    args = ["--deinterlace"] if deinterlace else []
    result = _invoke("fit", clip / "video0.avi", "--model", LOCUST / "model.xml",
                     "--rig", LOCUST / "rig.json", "--out", tmp_path, *args)
    assert result.exit_code == 0, result.output
    fusion = json.loads((tmp_path / "report.json").read_text())["settings"]["fit"]["fusion_px"]
    assert fusion == pytest.approx(fusion_distance(diameter))


@pytest.mark.parametrize(
    ("case", "match"),
    [("missing_model", "cannot read model"), ("bad_rig", "rig"), ("text_video", "video"),
     ("two_videos", "expects 1 video"), ("bad_histograms", "histogram"),
     ("bad_diameter", "--marker-diameter-px"),
     ("model_of_1000_joints", "one attempt on one image is estimated to take up to"),
     # refused before any video is read: the 'auto' diameter decodes up to 50 images
     ("model_of_1000_joints_and_a_text_video", "one attempt on one image is estimated to take up to")],
)
def test_bad_input_exits_2_with_one_line(clip, tmp_path, case, match):
    model, rig, video = LOCUST / "model.xml", LOCUST / "rig.json", clip / "video0.avi"
    extra: list = []
    videos = [video]
    if case == "missing_model":
        model = tmp_path / "nope.xml"
    elif case == "bad_rig":
        rig = tmp_path / "rig.json"
        rig.write_text('{"views": []}')
    elif case == "text_video":
        videos = [tmp_path / "notes.avi"]
        videos[0].write_text("not a video")
    elif case == "two_videos":
        videos = [video, video]
    elif case == "bad_diameter":
        extra = ["--marker-diameter-px", "-3"]
    elif case.startswith("model_of_1000_joints"):  # issue 12: one image's fit ran for hours
        model = tmp_path / "chain.xml"
        model.write_text(_chain_xml(1000))
        if case.endswith("text_video"):
            videos = [tmp_path / "notes.avi"]
            videos[0].write_text("not a video")
    else:
        bad = tmp_path / "h.xml"
        bad.write_text('<histograms model="x" bins="360"></histograms>')
        extra = ["--histograms", bad]
    result = _invoke("fit", *videos, "--model", model, "--rig", rig, "--out", tmp_path / "o",
                     *extra)
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mocap: error:")
    assert match in lines[0].lower()


@pytest.mark.parametrize(
    ("args", "match"),
    [(["fit", "v.avi", "--model", "m.xml", "--rig", "r.json", "--out", "o", "--jobs", "0"], "--jobs"),
     (["fit"], "missing argument"), (["fit", "v.avi", "--bogus"], "no such option"),
     (["fit", "v.avi", "--model", "m.xml", "--rig", "r.json", "--out", "o"], "cannot read model")],
)
def test_the_console_script_turns_usage_errors_into_one_line_and_exit_2(tmp_path, args, match):
    """The installed entry point (cli.app:run), not typer's test runner: what a user sees."""
    result = subprocess.run([sys.executable, "-c", "from cli.app import run; run()", *args],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mocap: error:"), result.stderr
    assert match in lines[0].lower()


def test_fit_with_root_tracking_follows_a_moving_body(tmp_path):
    """Rendered with a translating root, fitted with the fixed-root model and --root-marker."""
    phi = '<dof axis="y" name="phi"'
    text = (LOCUST / "model.xml").read_text().replace(
        phi, '<dof axis="tx" name="x" min="-10" max="10"/>\n    ' + phi)
    moving = tmp_path / "moving.xml"
    moving.write_text(text)
    synth = _invoke("synth", "--model", moving, "--rig", LOCUST / "rig.json", "--out", tmp_path / "clip",
                    "--samples", "20", "--seed", "8")
    assert synth.exit_code == 0, synth.output
    names, truth = read_truth_csv(tmp_path / "clip" / "truth.csv")
    start = ";".join(f"{240 + 3 * truth[0, 0]},{y}" for y in (184, 438))
    result = _fit(tmp_path / "clip", tmp_path / "out", "--root-marker", "M0", "--root-start", start)
    assert result.exit_code == 0, result.output
    table = read_angles_csv(tmp_path / "out" / "angles.csv")
    assert table.dof_names == names[1:]
    assert np.abs(table.dofs - truth[:, 1:]).max() < 1.0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["settings"]["root_tracking"]["marker"] == "M0"
