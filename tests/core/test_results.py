"""angles.csv (FORMATS §3) with its optional columns, and the per-marker error threshold."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from core.error import Detections
from core.examples import LOCUST
from core.fit import FitParams, ImageFit, Status
from core.histogram import Histograms
from core.model import KinematicModel
from core.results import (
    SampleClock,
    angles_header,
    read_angles_csv,
    read_truth_csv,
    write_angles_csv,
    write_truth_csv,
)
from core.rig import Rig
from core.sequence import fit_sequence


@pytest.fixture(scope="module")
def locust() -> tuple[KinematicModel, Rig]:
    return KinematicModel.from_xml(LOCUST / "model.xml"), Rig.from_json(LOCUST / "rig.json")


def _views(model, rig, q, noise_px, drop_view=None, seed=0) -> Detections:
    proj = rig.project(model.marker_positions(q))
    proj = proj + np.random.default_rng(seed).normal(0.0, noise_px, proj.shape)
    return Detections.from_views([np.zeros((0, 2)) if v == drop_view else p for v, p in enumerate(proj)])


def _fit_one(model, rig, det, threshold) -> ImageFit:
    params = FitParams(error_threshold_px=threshold, max_attempts=1, alternative_tolerance_px=0.0)
    return fit_sequence([det], model=model, rig=rig, histograms=Histograms.uniform(model),
                        params=params, seed=0).fits[0]


def test_the_threshold_is_compared_per_compared_marker_projection(locust):
    """Statuses follow error_px / (markers x views with detections), not error_px."""
    model, rig = locust
    q = np.array([170.0, 5.0, 2.0, 20.0, 80.0])
    det = _views(model, rig, q, noise_px=0.6)
    fit = _fit_one(model, rig, det, threshold=1.25)
    per_marker = fit.error / 8
    assert fit.error_per_marker(4) == pytest.approx(per_marker)
    assert 0.1 < per_marker < 1.25 and fit.status is Status.OK
    assert _fit_one(model, rig, det, threshold=0.5 * per_marker).status is Status.OVER_THRESHOLD
    one_view = _fit_one(model, rig, _views(model, rig, q, 0.6, drop_view=1), threshold=1.25)
    assert one_view.compared(4) == 4
    assert one_view.error_per_marker(4) == pytest.approx(one_view.error / 4)


def test_a_side_view_mirror_posture_fills_alternative_deg_and_keeps_the_status(tmp_path, locust):
    """The paper's Fig. 9 case: one view cannot tell a posture from its mirror image. The
    image is marked ambiguous by alternative_deg; its status stays what the error says."""
    model, rig = locust
    side = Rig((rig.views[0],))
    q = np.array([160.0, 15.0, 3.0, 20.0, 80.0])  # mirror 200, -15: inside the ranges
    det = _views(model, side, q, noise_px=0.0)
    fit = fit_sequence([det], model=model, rig=side, histograms=Histograms.uniform(model),
                       params=FitParams(choose_by_continuity=False), seed=0).fits[0]
    assert fit.status is Status.OK
    alt = fit.alternative_deg(model.rotational)
    assert alt == pytest.approx(40.0, abs=0.5)  # phi 160 <-> 200 (psi 15 <-> -15: 30)
    path = tmp_path / "angles.csv"
    write_angles_csv(path, model, [fit], SampleClock(50.0))
    table = read_angles_csv(path)
    assert table.alternative_deg[0] == pytest.approx(alt, abs=1e-3)
    assert table.error_per_marker[0] == pytest.approx(fit.error / 4, abs=1e-4)
    assert table.statuses == [Status.OK]


def test_the_header_puts_the_optional_columns_after_status(locust):
    model, _ = locust
    assert angles_header(model)[-5:] == ["error_px", "attempts", "status", "error_per_marker_px",
                                         "alternative_deg"]


def test_a_file_without_the_optional_columns_still_reads(tmp_path, locust):
    model, _ = locust
    header = angles_header(model)[:-2]
    path = tmp_path / "angles.csv"
    path.write_text(",".join(header) + "\n0,0,,0.000000,170,0,0,20,80,0.5000,1,ok\n")
    table = read_angles_csv(path)
    assert table.statuses == [Status.OK] and table.errors[0] == 0.5
    assert math.isnan(table.error_per_marker[0]) and math.isnan(table.alternative_deg[0])


def test_an_image_without_an_alternative_leaves_the_cell_empty(locust):
    model, rig = locust
    q = np.array([170.0, 5.0, 2.0, 20.0, 80.0])
    fit = _fit_one(model, rig, _views(model, rig, q, 0.0), threshold=1.25)
    text = io.StringIO()
    write_angles_csv(text, model, [fit], SampleClock(50.0))
    row = text.getvalue().splitlines()[1].split(",")
    assert row[-3] == "ok" and row[-1] == ""


# ---- truth.csv ----------------------------------------------------------------------------------


@pytest.mark.parametrize("interlaced", [False, True])
def test_truth_csv_round_trip_and_header(tmp_path, locust, interlaced):
    model, _ = locust
    q = np.array([[170.0, -0.5, 1e-7, 10.123456789012345, 90.0],
                  [120.0, 40.0, -10.0, 0.1 + 0.2, 160.0],
                  [200.0, 0.0, -0.0, 33.3, 20.0],
                  [150.5, 1.5, 2.5, 3.5, 45.0]])
    path = tmp_path / "truth.csv"
    write_truth_csv(path, model, q, fps=25.0, interlaced=interlaced)
    lines = path.read_text().splitlines()
    assert lines[0] == "sample,frame,field,time_s,phi,psi,alpha,beta,gamma"
    if interlaced:
        assert lines[1].startswith("0,0,even,0,170,-0.5,0.0000001,")
        assert lines[4].startswith("3,1,odd,0.06,")
    else:
        assert lines[1].startswith("0,0,,0,")
        assert lines[4].startswith("3,3,,0.12,")
    assert not any("e" in cell.lower() for line in lines[1:] for cell in line.split(",")[3:])
    names, back = read_truth_csv(path)
    assert names == model.dof_names
    np.testing.assert_array_equal(back, q)


def test_read_truth_csv_rejects_another_header(tmp_path):
    path = tmp_path / "other.csv"
    path.write_text("frame,phi\n0,1\n")
    with pytest.raises(ValueError, match="header"):
        read_truth_csv(path)


def test_ambiguous_dofs_count_the_dof_each_alternative_is_farthest_in_and_advise_past_half(locust):
    """report.json's ``ambiguous_dofs`` and its advice (``core.pipeline``): per DOF, the images
    whose best alternative is farthest from the posture in it; a line only when more than half
    of the fitted images are ambiguous, naming the three DOFs most often so, most often first."""
    from core.ambiguity import Candidate
    from core.pipeline import ambiguous_advice, ambiguous_dofs

    model, _ = locust
    q = (model.lower + model.upper) / 2

    def fit(moved: int | None) -> ImageFit:
        alternatives = ()
        if moved is not None:
            other = q.copy()
            other[moved] += 12.0
            other[(moved + 1) % len(q)] += 3.0  # a DOF moved less does not count
            alternatives = (Candidate(other, 0.2, 0.2),)
        return ImageFit(0, q, 0.1, 0.1, 1, Status.OK, 1, (4, 4), alternatives)

    names = model.dof_names
    fits = [fit(m) for m in (0, 2, 2, 3, 1, 2, 3, None)]
    by_dof = ambiguous_dofs(fits, model)
    assert by_dof == {names[0]: 1, names[1]: 1, names[2]: 3, names[3]: 2}
    assert ambiguous_advice(4, 8, by_dof) == []  # half: no line
    (line,) = ambiguous_advice(7, 8, by_dof)
    first = f"most often in {names[2]} (3), {names[3]} (2), {names[0]} (1): "
    assert line.startswith("7 of 8 images are ambiguous (another posture fits about as well: "
                           f"alternative_deg), {first}")
