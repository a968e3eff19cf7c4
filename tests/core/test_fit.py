"""Eq. 5, Simulated Annealing, refinement and the sequence flow (chunks, merge, re-analysis)."""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from core.anneal import AnnealParams, StopReason, anneal, search_space
from core.error import Detections, view_error
from core.fit import (
    FitParams,
    ImageFit,
    Status,
    fit_chunk,
    fit_sequence,
    needs_reanalysis,
    reanalyse_image,
    typical_objective,
)
from core.histogram import Histograms
from core.model import KinematicModel
from core.refine import refine
from core.rig import Rig

EXAMPLE = Path(__file__).parents[2] / "examples" / "locust_hind_leg"
FAST = AnnealParams(n_end=6000, n_l=600, n_tau=300)


@pytest.fixture(scope="module")
def locust() -> tuple[KinematicModel, Rig]:
    return (
        KinematicModel.from_xml(EXAMPLE / "model.xml"),
        Rig.from_json(EXAMPLE / "rig.json"),
    )


def _detections(model, rig, postures, noise=0.0, seed=0) -> list[Detections]:
    proj = rig.project(model.marker_positions(np.atleast_2d(postures)))
    proj = proj + np.random.default_rng(seed).normal(0.0, noise, proj.shape) if noise else proj
    return [Detections.from_views(list(p)) for p in proj]


def _postures(model, n, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(model.lower + 5, model.upper - 5, (n, 5))


# ---- Eq. 5 ---------------------------------------------------------------------------------


def test_eq5_by_hand(locust):
    """One marker per view, a known offset to the nearest of two detections, and a ghost."""
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    proj = rig.project(model.marker_positions(q))  # (2 views, 4 markers, 2)
    side = proj[0] + [3.0, 4.0]  # every marker 5 px off in the side view
    top = np.vstack([proj[1], [[5.0, 300.0]]])  # exact, plus a far ghost
    det = Detections.from_views([side, top])
    assert view_error(q, det, model=model, rig=rig) == pytest.approx(4 * 5.0)


def test_eq5_empty_view_is_a_constant_penalty(locust):
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    proj = rig.project(model.marker_positions(q))
    det = Detections.from_views([proj[0] + [0.0, 1.0], np.zeros((0, 2))])
    for penalty in (0.0, 5.0):
        e = view_error(q, det, model=model, rig=rig, empty_view_penalty_px=penalty)
        assert e == pytest.approx(4 * 1.0 + 4 * penalty)
    nothing = Detections.from_views([np.zeros((0, 2)), np.zeros((0, 2))])
    assert math.isfinite(view_error(q, nothing, model=model, rig=rig))


def test_eq5_offsets_shift_projections(locust):
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    det = _detections(model, rig, q)[0]
    offsets = np.array([[0.0, 2.0], [0.0, 0.0]])
    assert view_error(q, det, model=model, rig=rig, offsets=offsets) == pytest.approx(8.0)


def test_detections_mismatched_views_rejected(locust):
    model, rig = locust
    with pytest.raises(ValueError, match="views"):
        view_error(np.full(5, 100.0), Detections.from_views([np.zeros((1, 2))]), model=model, rig=rig)


# ---- Simulated Annealing ------------------------------------------------------------------------


def test_anneal_is_deterministic_per_seed(locust):
    model, rig = locust
    det = _detections(model, rig, _postures(model, 1), noise=0.1)[0]
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
    det = _detections(model, rig, _postures(model, 1, seed=4))[0]
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
    det = _detections(model, rig, np.array([200.0, 0, 0, 10, 90]))[0]
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


# ---- refinement --------------------------------------------------------------------------------


def test_refine_reaches_subpixel_from_a_nearby_posture(locust):
    model, rig = locust
    truth = np.array([160.0, 10.0, 3.0, 20.0, 100.0])
    det = _detections(model, rig, truth)[0]
    start = truth + np.array([1.5, -1.5, 1.0, -1.0, 2.0])
    refined = refine(start, det, model=model, rig=rig)
    assert view_error(refined, det, model=model, rig=rig) < 1e-6
    np.testing.assert_allclose(refined, truth, atol=1e-5)


def test_refine_respects_bounds(locust):
    model, rig = locust
    beyond = np.array([230.0, 0.0, 0.0, 10.0, 90.0])  # phi outside 120..220
    det = _detections(model, rig, np.clip(beyond, model.lower, model.upper))[0]
    refined = refine(beyond, det, model=model, rig=rig)
    assert np.all(refined <= model.upper) and np.all(refined >= model.lower)


# ---- sequences ---------------------------------------------------------------------------------


def test_fit_sequence_recovers_postures(locust):
    model, rig = locust
    truth = _postures(model, 12, seed=2)
    dets = _detections(model, rig, truth, noise=0.05, seed=2)
    result = fit_sequence(dets, model=model, rig=rig, histograms=Histograms.uniform(model),
                          params=FitParams(), seed=3)
    q = np.array([f.dofs for f in result.fits])
    errors = np.array([f.error for f in result.fits])
    assert all(f.status is Status.OK for f in result.fits)
    assert np.median(np.abs(q - truth)) < 0.2
    assert errors.mean() < 1.0


def test_chunked_fit_equals_fitting_the_chunks_and_merging(locust):
    """What workers do (chunks from the same prior, merged by counts) is what fit_sequence does."""
    model, rig = locust
    dets = _detections(model, rig, _postures(model, 6, seed=5), noise=0.05)
    prior = Histograms.uniform(model, prior_weight=20)
    params = FitParams(anneal=FAST)
    whole = fit_sequence(dets, model=model, rig=rig, histograms=prior, params=params, seed=9,
                         chunk_size=4)
    a = fit_chunk(dets[:4], model=model, rig=rig, histograms=prior, params=params, seed=9)
    b = fit_chunk(dets[4:], model=model, rig=rig, histograms=prior, params=params, seed=9,
                  first_sample=4)
    for got, want in zip(whole.fits, a.fits + b.fits, strict=True):
        np.testing.assert_array_equal(got.dofs, want.dofs)
    merged = prior.merge(a.observed, b.observed)
    np.testing.assert_allclose(whole.histograms.probs, merged.probs, atol=1e-12)
    np.testing.assert_allclose(whole.histograms.counts, merged.counts)


def test_single_chunk_histograms_equal_sequential_eq4_update(locust):
    model, rig = locust
    dets = _detections(model, rig, _postures(model, 5, seed=6), noise=0.05)
    prior = Histograms.uniform(model, prior_weight=10)
    result = fit_sequence(dets, model=model, rig=rig, histograms=prior,
                          params=FitParams(anneal=FAST), seed=1)
    expected = prior.copy()
    for fit in result.fits:
        expected.update(fit.dofs[model.rotational])
    np.testing.assert_allclose(result.histograms.probs, expected.probs, atol=1e-12)
    assert result.histograms.counts[0] == 10 + 5


def test_over_threshold_images_are_reanalysed_up_to_max_attempts(locust):
    model, rig = locust
    dets = _detections(model, rig, _postures(model, 2, seed=7), noise=0.3)
    params = FitParams(anneal=FAST, error_threshold_px=0.01, max_attempts=3)
    result = fit_sequence(dets, model=model, rig=rig, histograms=Histograms.uniform(model),
                          params=params, seed=2)
    for fit in result.fits:
        assert fit.attempts == 3
        assert fit.status is Status.OVER_THRESHOLD
        assert fit.error > 0.01
    # Unchanged histograms: no image was accepted.
    np.testing.assert_array_equal(result.histograms.counts, Histograms.uniform(model).counts)


def test_reanalyses_in_other_processes_equal_those_in_this_one(locust):
    """fit_sequence hands the re-analyses to ``map_chunks`` as well (``--jobs``): each image's
    attempts depend on nothing but itself and the merged histograms."""
    model, rig = locust
    dets = _detections(model, rig, _postures(model, 4, seed=7), noise=0.3)
    params = FitParams(anneal=FAST, error_threshold_px=0.01, max_attempts=3)
    kwargs = dict(model=model, rig=rig, histograms=Histograms.uniform(model), params=params,
                  seed=2, chunk_size=2)
    here = fit_sequence(dets, **kwargs)
    mapped = []
    with ProcessPoolExecutor(max_workers=2) as pool:
        def pool_map(fn, items):
            items = list(items)
            mapped.append(len(items))
            return pool.map(fn, items)

        there = fit_sequence(dets, map_chunks=pool_map, **kwargs)
    assert mapped == [2, 4]  # two chunks, then four images to re-analyse
    assert [f.attempts for f in there.fits] == [3, 3, 3, 3]
    for got, want in zip(there.fits, here.fits, strict=True):
        np.testing.assert_array_equal(got.dofs, want.dofs)
        assert got.objective == want.objective and got.sample == want.sample


def test_reanalysis_keeps_the_best_attempt(locust):
    model, rig = locust
    det = _detections(model, rig, _postures(model, 1, seed=8), noise=0.3)[0]
    params = FitParams(anneal=replace(FAST, n_end=300, n_tau=100, n_l=100, polish_every=0),
                       refine=False, error_threshold_px=0.01)
    prior = Histograms.uniform(model)
    first = fit_chunk([det], model=model, rig=rig, histograms=prior, params=params, seed=0).fits[0]
    errors = [first.error]
    fit = first
    for _ in range(3):
        fit = reanalyse_image(det, fit, model=model, rig=rig, histograms=prior, params=params,
                              seed=0)
        errors.append(fit.error)
    assert errors == sorted(errors, reverse=True)
    assert fit.attempts == 4
    assert fit.error == pytest.approx(view_error(fit.dofs, det, model=model, rig=rig))


def test_image_without_detections(locust):
    model, rig = locust
    empty = Detections.from_views([np.zeros((0, 2)), np.zeros((0, 2))])
    result = fit_sequence([empty], model=model, rig=rig, histograms=Histograms.uniform(model),
                          params=FitParams(anneal=FAST), seed=0)
    fit = result.fits[0]
    assert fit.status is Status.NO_DETECTIONS and fit.attempts == 0
    assert np.all(np.isnan(fit.dofs)) and math.isnan(fit.error)


def test_fit_chunk_should_stop_ends_early(locust):
    model, rig = locust
    dets = _detections(model, rig, _postures(model, 4))
    calls = iter([False, False, True, True])
    result = fit_chunk(dets, model=model, rig=rig, histograms=Histograms.uniform(model),
                       params=FitParams(anneal=FAST), seed=0, should_stop=lambda: next(calls))
    assert [f.sample for f in result.fits] == [0, 1]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"error_threshold_px": 0.0}, "error_threshold_px"), ({"max_attempts": 0}, "max_attempts"),
     ({"empty_view_penalty_px": -1.0}, "empty_view_penalty_px")],
)
def test_fit_params_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        FitParams(**kwargs)


@pytest.mark.parametrize("n", [1, 3, 7])
def test_solve_spd_matches_numpy(n):
    from core._kernels import solve_spd

    rng = np.random.default_rng(n)
    m = rng.normal(size=(n, n))
    a, b = m @ m.T + n * np.eye(n), rng.normal(size=n)
    np.testing.assert_allclose(solve_spd(a, b), np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)


def test_fused_markers_are_predicted_at_their_common_centroid(locust):
    """Two markers 2 px apart image as one blob at their midpoint (4 px markers)."""
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    proj = rig.project(model.marker_positions(q))
    side = proj[0].copy()
    side[1] = side[0] + [2.0, 0.0]  # pretend M1 projects 2 px from M0 ...
    fused = np.vstack([0.5 * (side[0] + side[1]), side[2:]])  # ... the camera sees one blob
    from core import _kernels

    moved = side[None].copy()
    out = np.empty_like(moved)
    _kernels.fuse_projections(moved, 4.0, out)
    np.testing.assert_allclose(out[0, 0], fused[0])
    np.testing.assert_allclose(out[0, 1], fused[0])
    np.testing.assert_allclose(out[0, 2:], side[2:])


def test_restarts_rescue_a_local_minimum(locust):
    """A one-iteration SA cannot converge; restarts run SA again while they find lower minima."""
    model, rig = locust
    det = _detections(model, rig, _postures(model, 1, seed=10))[0]
    tiny = replace(FAST, n_end=1, polish_every=0)
    no_restart = fit_chunk([det], model=model, rig=rig, histograms=Histograms.uniform(model),
                           params=FitParams(anneal=tiny, refine=False, restarts=0), seed=0)
    with_restarts = fit_chunk([det], model=model, rig=rig, histograms=Histograms.uniform(model),
                              params=FitParams(anneal=tiny, refine=False, restarts=5), seed=0)
    assert no_restart.fits[0].iterations == 1
    assert 2 <= with_restarts.fits[0].iterations <= 6
    assert with_restarts.fits[0].objective < no_restart.fits[0].objective


def test_a_restart_that_finds_the_same_minimum_ends_the_restarts(locust):
    """A displaced detection keeps the minimum above eps (but below a lost marker's penalty):
    restarting finds it again, and stops well before the 5 restarts allowed."""
    model, rig = locust
    q = np.array([170.0, 10.0, 0.0, 20.0, 90.0])
    proj = rig.project(model.marker_positions(q))
    proj[1, 3] += (3.0, 0.0)  # the top view's tarsus detection is 3 px off
    det = Detections.from_views(list(proj))
    fits = fit_chunk([det], model=model, rig=rig, histograms=Histograms.uniform(model),
                     params=FitParams(anneal=replace(FAST, patience=0), restarts=5), seed=0).fits
    assert fits[0].objective > FAST.eps
    assert np.abs(fits[0].dofs - q).max() < 1.0
    assert fits[0].iterations <= 3 * FAST.n_end < 6 * FAST.n_end


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
    q = _postures(model, 1, seed=seed)[0]
    det = _detections(model, rig, q)[0]
    frozen = replace(FAST, l0=1e-9, n_end=10, polish_every=1, patience=0)
    common = dict(model=model, rig=rig, space=search_space(model, Histograms.uniform(model)))
    alone = anneal(det, params=replace(frozen, draws=0), rng=np.random.default_rng(0), **common)
    drawn = anneal(det, params=replace(frozen, draws=32), rng=np.random.default_rng(0), **common)
    assert alone.error > 10.0 and alone.iterations == frozen.n_end
    assert drawn.stop is StopReason.BELOW_EPSILON
    assert np.abs(drawn.dofs - q).max() < 1.0  # the basin; eps (1 px) ends the search there


# ---- blobs, lost markers, outliers ------------------------------------------------------------


@pytest.mark.parametrize("gap_px", [3.0, 6.0])
def test_a_view_is_read_merged_or_apart_whichever_explains_it(locust, gap_px):
    """Markers 3 px apart show as one blob at their centroid, 6 px apart as two blobs: the
    blob reading scores both images 0; plain Eq. 5 charges the merged one 1.5 px a marker."""
    model, rig = locust
    side, top = rig.project(model.marker_positions(np.array([170.0, 0.0, 0.0, 10.0, 90.0])))
    top = top.copy()
    centre = top[2:].mean(axis=0)
    half = np.array([0.0, gap_px / 2])
    top[2], top[3] = centre - half, centre + half
    blobs = top if gap_px >= 5 else np.vstack([top[:2], centre])
    det = Detections.from_views([side, blobs])
    assert _eq5_at(side, top, det, fusion_px=8.0) == pytest.approx(0.0, abs=1e-9)
    assert _eq5_at(side, top, det) == pytest.approx(gap_px if gap_px < 5 else 0.0)


def _eq5_at(side, top, det, fusion_px=0.0):
    """The objective of imaged markers (side, top) against ``det``, through the kernel."""
    from core import _kernels

    raw = np.ascontiguousarray(np.stack([side, top]))
    fused = np.empty_like(raw)
    if fusion_px > 0:
        _kernels.fuse_projections(raw, fusion_px, fused)
    index, dist, claims = np.empty(4, dtype=np.int64), np.empty(4), np.empty(len(det.points), dtype=np.int64)
    return _kernels.blob_error(raw, fused, det.kernel_points, det.start, 5.0, fusion_px, 0.0, np.inf,
                               index, dist, claims, _kernels.NO_UNSEEN)


def test_a_blob_left_unexplained_beside_two_markers_on_one_blob_is_charged(locust):
    """Two markers put on one blob 6 px from another that nobody claims: the blob reading
    charges the lone blob its distance (6 px); plain Eq. 5 charges nothing."""
    model, rig = locust
    side = rig.project(model.marker_positions(np.array([170.0, 0.0, 0.0, 10.0, 90.0])))[0]
    top = np.array([[240.0, 438.0], [227.0, 438.0], [160.0, 440.0], [160.0, 440.5]])
    blobs = np.array([[240.0, 438.0], [227.0, 438.0], [160.0, 440.25], [160.0, 446.25]])
    det = Detections.from_views([side, blobs])
    assert _eq5_at(side, top, det) == pytest.approx(0.5)
    assert _eq5_at(side, top, det, fusion_px=8.0) == pytest.approx(6.0, abs=0.3)


def test_a_lost_marker_does_not_drag_the_posture(locust):
    """The trochanter marker M1 missing from the side view (charged its ~10 px to M0's blob):
    the refit without it puts the leg where the other markers and the top view say."""
    model, rig = locust
    q = np.array([150.0, 20.0, 0.0, 20.0, 90.0])
    proj = rig.project(model.marker_positions(q))
    det = Detections.from_views([proj[0][[0, 2, 3]], proj[1]])
    fits = fit_chunk([det], model=model, rig=rig, histograms=Histograms.uniform(model),
                     params=FitParams(fusion_px=8.0), seed=1).fits
    assert np.abs(fits[0].dofs - q).max() < 0.2
    assert fits[0].objective == pytest.approx(5.0, abs=0.2)  # the lost marker's flat charge


def test_outliers_are_reanalysed_as_if_over_the_threshold():
    params = FitParams()
    fit = ImageFit(0, np.zeros(5), 6.0, 6.0, 1, Status.OK, 500, (4, 4))
    assert typical_objective([fit, replace(fit, objective=0.1), replace(fit, objective=0.2)]) == 0.2
    assert needs_reanalysis(fit, params, typical=0.1)  # 60x the typical objective
    assert not needs_reanalysis(fit, params, typical=1.0)  # 6x
    assert not needs_reanalysis(fit, replace(params, outlier_factor=0.0), typical=0.1)
    assert not needs_reanalysis(replace(fit, objective=0.9), params, typical=0.01)  # below eps
    assert not needs_reanalysis(replace(fit, attempts=params.max_attempts), params, typical=0.1)
    assert needs_reanalysis(replace(fit, status=Status.OVER_THRESHOLD), params)
