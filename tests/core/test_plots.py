"""Angle and histogram plots: valid PNG and SVG files with one axis per DOF."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import defusedxml.ElementTree as SafeET
import numpy as np
import pytest

from core.examples import LOCUST
from core.fit import Status
from core.histogram import Histograms
from core.model import KinematicModel
from core.plots import MAX_PLOT_DOFS, angles_figure, histogram_interval, write_plots
from core.results import AnglesTable

SVG_G = "{http://www.w3.org/2000/svg}g"


def sequence(model: KinematicModel, n: int = 30) -> tuple[AnglesTable, Histograms]:
    """n images moving through the middle of each DOF's range, some marked; the final histograms."""
    rng = np.random.default_rng(0)
    mid, half = (model.lower + model.upper) / 2, (model.upper - model.lower) / 4
    dofs = mid + half * np.sin(np.linspace(0, 3, n))[:, None] + rng.normal(0, 1, (n, len(mid)))
    statuses = [Status.OVER_THRESHOLD if i in (5, 17) else Status.OK for i in range(n)]
    alternative = np.full(n, np.nan)
    alternative[[8, 9]] = 40.0
    table = AnglesTable(
        dof_names=model.dof_names, samples=np.arange(n), frames=np.arange(n), fields=[""] * n,
        times=np.arange(n) / 50.0, dofs=dofs, errors=rng.uniform(0, 3, n),
        attempts=np.where(np.isin(np.arange(n), [5, 17, 20]), 3, 1), statuses=statuses,
        error_per_marker=np.full(n, np.nan), alternative_deg=alternative,
    )
    final = Histograms.uniform(model)
    for row in dofs[:, model.rotational]:
        final.update(row)
    return table, final


def axes_in_svg(path: Path) -> int:
    """matplotlib writes each axis as a group with id 'axes_<n>'."""
    root = SafeET.parse(path).getroot()
    return sum(1 for g in root.iter(SVG_G) if g.get("id", "").startswith("axes_"))


def test_plots_are_valid_png_and_svg_with_one_axis_per_dof(tmp_path):
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    table, final = sequence(model)
    names = write_plots(tmp_path, table, model, Histograms.uniform(model), final)
    assert names == ["angles.png", "angles.svg", "histograms.png", "histograms.svg"]
    for name in ("angles.png", "histograms.png"):
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.shape[0] > 300 and image.shape[1] > 300
        assert (image < 250).any()  # something drawn on the white background
    assert axes_in_svg(tmp_path / "angles.svg") == len(model.dofs) == 5
    assert axes_in_svg(tmp_path / "histograms.svg") == int(model.rotational.sum())
    before = (tmp_path / "angles.svg").read_bytes()
    write_plots(tmp_path, table, model, Histograms.uniform(model), final)
    assert (tmp_path / "angles.svg").read_bytes() == before  # no date, fixed ids: reproducible


def test_the_angle_figure_marks_what_the_table_says():
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    table, final = sequence(model)
    figure = angles_figure(table, model, final)
    lines = {line.get_label(): line for line in figure.axes[0].get_lines()}
    np.testing.assert_allclose(lines["over threshold"].get_xdata(), [0.10, 0.34])
    np.testing.assert_allclose(lines["ambiguous"].get_xdata(), [0.16, 0.18])
    np.testing.assert_allclose(lines["re-analysed"].get_xdata(), [0.10, 0.34, 0.40])
    assert figure.axes[0].get_ylim() == (model.dofs[0].min, model.dofs[0].max)
    # each axis names its DOF inside it, the unit alone on the y axis (a y label of a long
    # name, R1_metatarsus_pitch (deg), was clipped)
    assert [[t.get_text() for t in ax.texts] for ax in figure.axes] == [[d.name] for d in model.dofs]
    assert [ax.get_ylabel() for ax in figure.axes] == ["deg"] * len(model.dofs)


def test_histogram_interval_holds_the_central_mass():
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    h = Histograms.empty(model)
    h.update(np.array([170.5, 0.5, 359.5, 10.5, 90.5]))  # one count per DOF
    assert histogram_interval(h, 0) == (170.0, 171.0)
    assert histogram_interval(h, 2) == (359.0, 360.0) or histogram_interval(h, 2) == (-1.0, 0.0)
    lo, hi = histogram_interval(Histograms.uniform(model), 4)  # gamma: 20..160
    assert lo == pytest.approx(27.0, abs=1.5) and hi == pytest.approx(153.0, abs=1.5)  # 5 % of 140 deg in


def test_too_many_dofs_is_a_clear_error():
    def joint(i: int) -> str:
        parent = f' parent="j{i - 1}"' if i else ""
        return (f'<joint name="j{i}"{parent}><offset x="1" y="0" z="0"/>'
                f'<dof axis="z" name="d{i}" min="0" max="10"/></joint>')

    joints = "".join(joint(i) for i in range(MAX_PLOT_DOFS + 1))
    model = KinematicModel.from_xml(f'<model name="long">{joints}<marker name="M" joint="j0" x="0" '
                                    'y="0" z="0"/></model>')
    table, final = sequence(model, 12)
    with pytest.raises(ValueError, match=f"at most {MAX_PLOT_DOFS}"):
        angles_figure(table, model, final)


def test_importing_core_does_not_import_matplotlib():
    code = "import sys, core, core.plots, core.overlay; print('matplotlib' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.stdout.strip() == "False", result.stderr
