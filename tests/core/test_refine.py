"""Levenberg–Marquardt refinement (core.refine): sub-pixel from a nearby posture, within the bounds."""

from __future__ import annotations

import numpy as np
from scenes import detections

from core.error import view_error
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

