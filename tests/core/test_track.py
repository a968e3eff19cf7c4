"""Root tracking (paper §2.1): validation, next-neighbour by hand, and a moving root fitted."""

from __future__ import annotations

import numpy as np
import pytest

from core.detect import detect
from core.error import Detections
from core.examples import LOCUST
from core.fit import FitParams
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig
from core.sequence import fit_sequence
from core.synth import render_frames
from core.track import RootTracking, root_reference, track_root


@pytest.fixture(scope="module")
def locust() -> tuple[KinematicModel, Rig]:
    return KinematicModel.from_xml(LOCUST / "model.xml"), Rig.from_json(LOCUST / "rig.json")


def _moving_root_model() -> KinematicModel:
    """The locust leg whose root also translates along x and z (a walking body)."""
    text = (LOCUST / "model.xml").read_text()
    text = text.replace('<dof axis="y" name="phi"', '<dof axis="tx" name="x" min="-15" max="15"/>\n'
                        '    <dof axis="tz" name="z" min="-15" max="15"/>\n    <dof axis="y" name="phi"')
    return KinematicModel.from_xml(text)


def test_the_reference_is_the_root_markers_projection(locust):
    model, rig = locust
    np.testing.assert_allclose(root_reference(model, rig, "M0"), [[240.0, 184.0], [240.0, 438.0]])


@pytest.mark.parametrize(("marker", "match"), [("M9", "not a marker"), ("M1", "origin of the root")])
def test_a_root_marker_must_be_at_the_root_origin(locust, marker, match):
    model, rig = locust
    with pytest.raises(ValueError, match=match):
        root_reference(model, rig, marker)


def test_a_root_with_translational_dofs_cannot_also_be_tracked(locust):
    with pytest.raises(ValueError, match="translational"):
        root_reference(_moving_root_model(), locust[1], "M0")


@pytest.mark.parametrize("kwargs", [{"max_jump_px": 0.0}, {"start": ((1.0,),)}, {"start": ((np.nan, 1.0),)}])
def test_tracking_settings_are_validated(kwargs):
    with pytest.raises(ValueError):
        RootTracking("M0", **kwargs)


def test_next_neighbour_follows_the_marker_past_ghosts_and_keeps_it_when_lost():
    reference = np.array([[100.0, 100.0]])
    images = [
        Detections.from_views([[[103.0, 100.0], [140.0, 100.0]]]),  # marker moved 3 px; a ghost
        Detections.from_views([[[106.0, 101.0], [104.0, 130.0]]]),
        Detections.from_views([[[160.0, 101.0]]]),  # only a far ghost: lost, keep position
        Detections.from_views([np.zeros((0, 2))]),  # nothing detected: keep position
        Detections.from_views([[[108.0, 103.0]]]),
    ]
    offsets = track_root(images, reference=reference, tracking=RootTracking("M0", max_jump_px=10.0))
    np.testing.assert_allclose(offsets[:, 0], [[3, 0], [6, 1], [6, 1], [6, 1], [8, 3]])


def test_a_start_position_per_view_is_required_to_match_the_rig():
    images = [Detections.from_views([[[0.0, 0.0]], [[0.0, 0.0]]])]
    with pytest.raises(ValueError, match="start has 1"):
        track_root(images, reference=np.zeros((2, 2)), tracking=RootTracking("M0", ((1.0, 2.0),)))


def test_a_moving_root_is_tracked_and_the_leg_fitted(locust):
    model, rig = locust
    moving = _moving_root_model()
    rng = np.random.default_rng(5)
    n = 24
    t = np.linspace(0.0, 1.0, n)
    legs = np.column_stack([160 + 30 * t, 10 - 20 * t, 5 * np.sin(6 * t), 20 + 20 * t, 60 + 60 * t])
    body = np.column_stack([-8 + 16 * t, 6 * np.sin(3 * t)])  # x, z in mm
    truth = np.column_stack([body, legs])
    detections = [detect([f], rig=rig) for f in render_frames(moving, rig, truth, rng=rng)]
    reference = root_reference(model, rig, "M0")
    start = rig.project(moving.marker_positions(truth[0]))[:, 0]
    tracking = RootTracking("M0", tuple(map(tuple, start)), max_jump_px=10.0)
    offsets = track_root(detections, reference=reference, tracking=tracking)
    true_offsets = rig.project(moving.marker_positions(truth))[:, :, 0] - reference
    assert np.abs(offsets - true_offsets).max() < 0.1
    result = fit_sequence(detections, model=model, rig=rig, histograms=Histograms.uniform(model),
                          params=FitParams(fusion_px=4.0), seed=2, offsets=list(offsets))
    fitted = np.array([f.dofs for f in result.fits])
    assert np.abs(fitted - legs).max() < 1.0
    assert all(f.error < 1.0 for f in result.fits)
