"""Images that do not determine a DOF get an alternative; determined ones do not (core.undetermined).

With markers off the model by a pixel (sliding skin), the tolerance within which postures
count as alike grows with the image's own residual, and a DOF that can move more than
``UNDETERMINED_DEG`` within it is reported through ``alternative_deg``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.ambiguity import Candidate, angle_gaps
from core.error import Detections, view_error
from core.examples import EXAMPLES
from core.fit import FitParams, alternative_tolerance
from core.histogram import Histograms
from core.model import KinematicModel
from core.refine import refine
from core.rig import Rig
from core.sequence import fit_sequence
from core.undetermined import (
    UNDETERMINED_DEG,
    confidence_chi2,
    residual_tolerance,
    undetermined_alternative,
)

# The stick insect with its tibia almost straight (gamma near its 10 deg minimum): psi turns
# the leg about the femur, on whose axis the femur marker sits, so only the tibia marker's
# small sideways swing tells psi; a pixel of marker scatter hides tens of degrees of it.
STICK_STRAIGHT = np.array([0.0, 10.0, 190.0, 10.0, 15.0, 12.0])
LOCUST = np.array([160.0, 15.0, 3.0, 20.0, 80.0])


def _subject(name: str) -> tuple[KinematicModel, Rig]:
    return (KinematicModel.from_xml(EXAMPLES / name / "model.xml"),
            Rig.from_json(EXAMPLES / name / "rig.json"))


def _scattered(model: KinematicModel, rig: Rig, q: np.ndarray, px: float, seed: int) -> Detections:
    """Exact projections of ``q``, each moved by a normal scatter of ``px`` per coordinate."""
    proj = rig.project(model.marker_positions(q))
    return Detections.from_views(list(proj + np.random.default_rng(seed).normal(0, px, proj.shape)))


def _witness(model: KinematicModel, rig: Rig, det: Detections, q: np.ndarray):
    fit = refine(q, det, model=model, rig=rig)
    error = view_error(fit, det, model=model, rig=rig)
    tolerance = alternative_tolerance(FitParams(), det, model, error, 1)
    found = undetermined_alternative(Candidate(fit, error, error), det, model=model, rig=rig,
                                     tolerance_px=tolerance, fusion_px=0.0,
                                     empty_view_penalty_px=5.0, huber_px=1.0)
    return fit, error, tolerance, found


def test_chi2_quantiles_are_within_one_percent_of_the_table():
    for k, exact in ((1, 6.635), (2, 9.210), (6, 16.812), (42, 66.206)):
        assert confidence_chi2(k) == pytest.approx(exact, rel=0.01)


def test_the_residual_tolerance_per_projection_arithmetic():
    # 8 px over 8 projections: 1 px each; 16 coordinates, 6 DOFs absorbed.
    assert residual_tolerance(8.0, 8, 6, 1) == pytest.approx(confidence_chi2(1) * 1.0 * 16 / (10 * math.pi))
    # Linear in the mean distance per projection: the same mean over 80 projections gives
    # about the same tolerance (a little less: the DOFs absorb a smaller share).
    assert residual_tolerance(16.0, 8, 6, 1) == pytest.approx(2 * residual_tolerance(8.0, 8, 6, 1))
    assert residual_tolerance(80.0, 80, 6, 1) < residual_tolerance(8.0, 8, 6, 1)
    assert residual_tolerance(80.0, 80, 6, 1) == pytest.approx(
        confidence_chi2(1) * 160 / (154 * math.pi))
    assert residual_tolerance(8.0, 8, 6, 6) > residual_tolerance(8.0, 8, 6, 1)
    assert residual_tolerance(math.nan, 8, 6, 1) == 0.0
    assert residual_tolerance(1.0, 0, 6, 1) == 0.0


def test_clean_images_keep_the_fixed_tolerance_and_zero_turns_it_off():
    model, _ = _subject("locust_hind_leg")
    det = Detections.from_views([np.zeros((4, 2))] * 2)  # 4 markers x 2 views: 8 projections
    assert alternative_tolerance(FitParams(), det, model, 0.4, 5) == 0.5
    assert alternative_tolerance(FitParams(), det, model, 8.0, 1) == pytest.approx(
        residual_tolerance(8.0, 8, 5, 1))
    assert alternative_tolerance(FitParams(alternative_tolerance_px=0.0), det, model, 8.0, 1) == 0.0


def test_an_undetermined_dof_gets_a_witness_within_the_tolerance():
    model, rig = _subject("stick_insect_front_leg")
    det = _scattered(model, rig, STICK_STRAIGHT, 1.0, seed=1)
    fit, error, tolerance, found = _witness(model, rig, det, STICK_STRAIGHT)
    assert found is not None
    gaps = angle_gaps(found.dofs, fit)[model.rotational]
    assert gaps.max() >= UNDETERMINED_DEG
    assert gaps[model.dof_names.index("psi")] >= UNDETERMINED_DEG  # the femur's own axis
    assert found.objective <= error + tolerance
    assert found.error == pytest.approx(view_error(found.dofs, det, model=model, rig=rig))
    assert np.all((found.dofs >= model.lower) & (found.dofs <= model.upper))


@pytest.mark.parametrize("px", [0.0, 0.3])
def test_a_determined_posture_gets_no_witness(px):
    model, rig = _subject("locust_hind_leg")
    det = _scattered(model, rig, LOCUST, px, seed=2)
    assert _witness(model, rig, det, LOCUST)[3] is None


def test_the_fit_reports_alternative_deg_only_where_a_dof_is_undetermined():
    """Through ``fit_sequence``: the straight stick insect leg under a pixel of scatter is
    ambiguous (``alternative_deg`` >= 10 deg), the clearly seen locust leg is not."""
    for name, q, px, undetermined in (("stick_insect_front_leg", STICK_STRAIGHT, 1.0, True),
                                       ("locust_hind_leg", LOCUST, 0.3, False)):
        model, rig = _subject(name)
        images = [_scattered(model, rig, q, px, seed=s) for s in range(3)]
        result = fit_sequence(images, model=model, rig=rig, params=FitParams(), seed=0,
                              histograms=Histograms.uniform(model, prior_weight=100.0))
        degs = [f.alternative_deg(model.rotational) for f in result.fits]
        if undetermined:
            assert all(d >= UNDETERMINED_DEG for d in degs), (name, degs)
        else:
            assert all(math.isnan(d) for d in degs), (name, degs)
