"""Levenberg–Marquardt refinement (core.refine): sub-pixel from a nearby posture, within the bounds."""

from __future__ import annotations

import numpy as np
from scenes import detections

from bench.subjects import load
from core.error import Detections, view_error
from core.refine import refine


def test_refine_reaches_subpixel_from_a_nearby_posture(locust):
    model, rig = locust
    truth = np.array([160.0, 10.0, 3.0, 20.0, 100.0])
    det = detections(model, rig, truth)[0]
    start = truth + np.array([1.5, -1.5, 1.0, -1.0, 2.0])
    refined = refine(start, det, model=model, rig=rig)
    assert view_error(refined, det, model=model, rig=rig) < 1e-6
    np.testing.assert_allclose(refined, truth, atol=1e-5)


def test_refine_respects_bounds(locust):
    model, rig = locust
    beyond = np.array([230.0, 0.0, 0.0, 10.0, 90.0])  # phi outside 120..220
    det = detections(model, rig, np.clip(beyond, model.lower, model.upper))[0]
    refined = refine(beyond, det, model=model, rig=rig)
    assert np.all(refined <= model.upper) and np.all(refined >= model.lower)


def test_a_marker_hidden_beside_another_blob_does_not_pull_a_whole_animal_off_its_posture():
    """Every marker of the rat in turn hidden from the right camera, a blob 3 px from where it
    would be: refined from the true posture, the rest of the clean markers hold it (within
    0.1°). A Huber radius of 1 px everywhere let them give way by up to 0.5°, each of their
    residuals below the radius nearly free against the hidden marker's pull."""
    rat = load("rat")
    model, rig = rat.model, rat.rig
    truth = rat.trajectory(3, np.random.default_rng(0))[2]
    proj = rig.project(model.marker_positions(truth[None]))[0]
    for m in range(len(model.markers)):
        others = np.delete(proj[0], m, axis=0)
        det = Detections.from_views([np.vstack([others, proj[0, m] + [3.0, 0.0]]), *proj[1:]])
        refined = refine(truth, det, model=model, rig=rig)
        gaps = np.abs(refined - truth)[model.rotational]
        assert gaps.max() < 0.1, (model.markers[m].name, gaps.max())
