"""Natural movements (core.movement): ranges, rois, jumps between sequences, kicks."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scenes import dots_model, pixel_rig

from core.movement import natural_movements


def _check_movements(model, rig, q, n_sequences, margin, frame_size=(720, 576)):
    span = model.upper - model.lower
    inset = np.where(model.rotational, np.minimum(3.0, 0.1 * span), 0.05 * span)
    assert np.all(q >= model.lower + inset - 1e-9) and np.all(q <= model.upper - inset + 1e-9)
    proj = rig.project(model.marker_positions(q))  # (T, V, M, 2)
    for v, view in enumerate(rig.views):
        x, y, w, h = view.roi or (0, 0, *frame_size)
        assert np.all(proj[:, v] >= np.array([x, y]) + margin - 1e-9)
        assert np.all(proj[:, v] <= np.array([x + w, y + h]) - margin + 1e-9)
    bounds = np.cumsum([0] + [len(a) for a in np.array_split(np.arange(len(q)), n_sequences)])
    for b in bounds[1:-1]:  # a jump between sequences
        assert np.max(np.abs(q[b] - q[b - 1]) / span) >= 0.2
    for b0, b1 in itertools.pairwise(bounds):  # a kick in every sequence
        seq = q[b0:b1]
        sweep = max(np.max(np.abs(seq[k:] - seq[:-k]) / span) for k in range(2, 5))
        assert sweep >= 0.5


def test_natural_movements_stay_in_ranges_and_rois_with_jumps_and_kicks(locust):
    model, rig = locust
    q = natural_movements(model, rig, 240, rng=np.random.default_rng(11), n_sequences=4)
    assert q.shape == (240, 5) and q.dtype == np.float64
    _check_movements(model, rig, q, 4, 8.0)
    again = natural_movements(model, rig, 240, rng=np.random.default_rng(11), n_sequences=4)
    np.testing.assert_array_equal(q, again)
    # Smooth between kicks: most steps are small.
    steps = np.abs(np.diff(q, axis=0)) / (model.upper - model.lower)
    assert np.median(steps.max(axis=1)) < 0.05


def test_natural_movements_work_for_any_model():
    model = dots_model((0, 0), (10, 5))
    rig = pixel_rig([0, 0, 128, 96])
    q = natural_movements(model, rig, 60, rng=np.random.default_rng(2), n_sequences=3, margin_px=4)
    _check_movements(model, rig, q, 3, 4.0)


def test_natural_movements_refuse_impossible_rois(locust):
    model, _ = locust
    tiny = pixel_rig([0, 0, 10, 10])
    with pytest.raises(ValueError, match="roi"):
        natural_movements(model, tiny, 20, rng=np.random.default_rng(0), n_sequences=1)
