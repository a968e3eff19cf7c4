"""Simulated Annealing (core.anneal, Eq. 6): determinism per seed, bounds, plausibility, stopping."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scenes import FAST, detections, postures

from core.anneal import AnnealParams, StopReason, anneal, search_space
from core.error import Detections
from core.histogram import Histograms


def test_anneal_is_deterministic_per_seed(locust):
    model, rig = locust
    det = detections(model, rig, postures(model, 1), noise=0.1)[0]
    space = search_space(model, Histograms.uniform(model))
    params = replace(FAST, polish_every=0)
    runs = [
        anneal(det, model=model, rig=rig, space=space, params=params, rng=np.random.default_rng(s))
        for s in (7, 7, 8)
    ]
    np.testing.assert_array_equal(runs[0].dofs, runs[1].dofs)
    assert runs[0].error == runs[1].error
    assert not np.array_equal(runs[0].dofs, runs[2].dofs)


def test_anneal_stays_in_range_and_stops_below_epsilon(locust):
    model, rig = locust
    det = detections(model, rig, postures(model, 1, seed=4))[0]
    space = search_space(model, Histograms.uniform(model))
    result = anneal(det, model=model, rig=rig, space=space, params=AnnealParams(),
                    rng=np.random.default_rng(0))
    assert np.all(result.dofs >= model.lower) and np.all(result.dofs <= model.upper)
    assert result.stop is StopReason.BELOW_EPSILON and result.error < 1.0
    assert result.iterations < AnnealParams().n_end


def test_anneal_redraws_implausible_angles(locust):
    """With T_h above every bin outside 150..160 of phi, the search never leaves that band."""
    model, rig = locust
    hist = Histograms.uniform(model)
    hist.probs[0] = 0.0
    hist.probs[0, 150:160] = 0.1
    det = detections(model, rig, np.array([200.0, 0, 0, 10, 90]))[0]
    space = search_space(model, hist)
    params = replace(FAST, polish_every=0, plausibility_threshold=0.05)
    result = anneal(det, model=model, rig=rig, space=space, params=params,
                    rng=np.random.default_rng(1))
    assert 150.0 <= result.dofs[0] < 160.0


@pytest.mark.parametrize(
    ("field", "value"),
    [("n_end", 0), ("n_l", -1), ("n_tau", 1.5), ("tau0", 0.0), ("l0", -1.0), ("c_l", 1.5),
     ("c_tau", 0.0), ("eps", -1.0), ("plausibility_threshold", 1.0), ("huber_px", 0.0),
     ("polish_every", -1), ("polish_every", 2.5), ("draws", -1), ("draws", 2.5)],
)
def test_anneal_params_validation(field, value):
    with pytest.raises(ValueError, match=field):
        AnnealParams(**{field: value})


def test_patience_stops_annealing_once_the_best_stops_improving(locust):
    model, rig = locust
    q = np.array([170.0, 10.0, 0.0, 20.0, 90.0])
    proj = rig.project(model.marker_positions(q))
    proj[1, 3] += (3.0, 0.0)
    det = Detections.from_views(list(proj))
    space = search_space(model, Histograms.uniform(model))
    common = dict(model=model, rig=rig, space=space, rng=np.random.default_rng(1))
    patient = anneal(det, params=replace(FAST, patience=3), **common)
    endless = anneal(det, params=replace(FAST, patience=0), **common)
    assert endless.iterations == FAST.n_end
    assert patient.iterations < FAST.n_end
    assert patient.error == pytest.approx(endless.error, rel=0.05)


@pytest.mark.parametrize("seed", [0, 4])
def test_postures_drawn_at_polish_rounds_find_a_basin_sa_cannot_reach(locust, seed):
    """SA frozen at its start (step 1e-9) polishes a wrong basin; the best of the postures
    drawn from the histograms at each polish round, polished, finds the posture."""
    model, rig = locust
    q = postures(model, 1, seed=seed)[0]
    det = detections(model, rig, q)[0]
    frozen = replace(FAST, l0=1e-9, n_end=10, polish_every=1, patience=0)
    common = dict(model=model, rig=rig, space=search_space(model, Histograms.uniform(model)))
    alone = anneal(det, params=replace(frozen, draws=0), rng=np.random.default_rng(0), **common)
    drawn = anneal(det, params=replace(frozen, draws=32), rng=np.random.default_rng(0), **common)
    assert alone.error > 10.0 and alone.iterations == frozen.n_end
    assert drawn.stop is StopReason.BELOW_EPSILON
    assert np.abs(drawn.dofs - q).max() < 1.0  # the basin; eps (1 px) ends the search there

