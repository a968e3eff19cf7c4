"""Depth-flip alternatives and the choice among them by continuity (core.ambiguity)."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np
import pytest

from core.ambiguity import Candidate, FlipGeometry, choose_candidates, flip_alternatives
from core.error import Detections, view_error
from core.examples import LOCUST
from core.fit import FitParams, ImageFit, Status
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig
from core.sequence import finish_sequence, fit_sequence


@pytest.fixture(scope="module")
def locust() -> tuple[KinematicModel, Rig, Rig]:
    """The locust leg with its two-view rig and the side view alone."""
    rig = Rig.from_json(LOCUST / "rig.json")
    return KinematicModel.from_xml(LOCUST / "model.xml"), rig, Rig((rig.views[0],))


def _exact(model, rig, q) -> Detections:
    return Detections.from_views(list(rig.project(model.marker_positions(q))))


def _mirror(q: np.ndarray) -> np.ndarray:
    """The side view's reflection z -> -z: phi -> 360 - phi, psi -> -psi (leg plane kept)."""
    return np.array([360.0 - q[0], -q[1], *q[2:]])


def _alternatives(model, rig, q, det, tolerance=0.5):
    fit = Candidate(q, view_error(q, det, model=model, rig=rig), view_error(q, det, model=model, rig=rig))
    return flip_alternatives(fit, det, model=model, rig=rig, geometry=FlipGeometry.of(model, rig),
                             tolerance_px=tolerance, fusion_px=0.0, empty_view_penalty_px=5.0,
                             huber_px=1.0)


def test_the_geometry_lists_joints_with_dofs_and_what_lies_below_them(locust):
    model, _, side = locust
    geo = FlipGeometry.of(model, side)
    assert geo.flip_joints.tolist() == [0, 1, 2]  # body_coxa, trochanter_femur, femur_tibia
    assert geo.subtree_markers.tolist() == [[True] * 4, [False, True, True, True],
                                            [False, False, True, True]]
    np.testing.assert_allclose(np.abs(geo.depth[0]), [0.0, 0.0, 1.0])  # the side view loses z
    assert geo.masks.tolist() == list(range(1, 8))


def test_one_view_finds_the_mirror_posture_it_cannot_tell_apart(locust):
    model, _, side = locust
    q = np.array([160.0, 15.0, 3.0, 20.0, 80.0])
    det = _exact(model, side, q)
    found = _alternatives(model, side, q, det)
    assert any(np.abs(c.dofs - _mirror(q)).max() < 0.05 for c in found)
    assert all(c.objective < 0.5 for c in found)


def test_a_mirror_outside_the_range_is_not_an_alternative(locust):
    model, _, side = locust
    q = np.array([130.0, 15.0, 3.0, 20.0, 80.0])  # 360 - 130 = 230 > max 220
    found = _alternatives(model, side, q, _exact(model, side, q))
    assert not any(np.abs(c.dofs[1] - (-15.0)) < 1.0 and c.dofs[0] > 200 for c in found)


def test_two_views_leave_no_alternative_to_a_clear_posture(locust):
    model, rig, _ = locust
    q = np.array([160.0, 15.0, 3.0, 20.0, 80.0])
    assert _alternatives(model, rig, q, _exact(model, rig, q)) == []


def _cands(*postures: list[float], objective: float = 0.01) -> list[Candidate]:
    return [Candidate(np.array(p, dtype=float), objective, objective) for p in postures]


def test_continuity_keeps_one_branch_whatever_order_the_fits_came_in():
    truth = [[10.0 + k, 5.0] for k in range(6)]
    mirror = [[-10.0 - k, -5.0] for k in range(6)]
    run = [_cands(truth[0])]  # pinned: the mirror is impossible here
    run += [_cands(mirror[k], truth[k]) if k % 2 else _cands(truth[k], mirror[k]) for k in range(1, 6)]
    chosen = choose_candidates(run)
    assert [run[k][c].dofs.tolist() for k, c in enumerate(chosen)] == truth


def test_a_much_better_objective_wins_over_continuity():
    run = [_cands([0.0]), _cands([0.5]), [Candidate(np.array([1.0]), 0.9, 0.9),
                                          Candidate(np.array([30.0]), 0.01, 0.01)]]
    assert choose_candidates(run)[2] == 1


def test_a_charge_for_projections_beyond_the_edges_does_not_dilute_a_much_better_objective():
    """Every image pays 25 px for markers beyond a frame's edge, its fit 1 px more. At
    image 2 the candidate that stays put scores 10 px worse than one that jumps: read
    against a typical objective of 26 px, the move outweighs it; read against the 1 px the
    images do not explain, the objective wins, as it does without the charge."""
    run = [_cands([0.0], objective=26.0), _cands([0.5], objective=26.0),
           [Candidate(np.array([1.0]), 36.0, 36.0), Candidate(np.array([30.0]), 26.0, 26.0)]]
    assert choose_candidates(run)[2] == 0
    assert choose_candidates(run, [25.0, 25.0, 25.0])[2] == 1


def test_an_image_without_detections_breaks_the_chain():
    run = [_cands([10.0]), [], _cands([-11.0], [11.0]), _cands([-12.0], [12.0])]
    assert choose_candidates(run) == [0, 0, 0, 0]  # after the break nothing pins the branch
    run = [_cands([10.0]), _cands([-11.0], [11.0]), [], _cands([-12.0], [12.0])]
    assert choose_candidates(run)[1] == 1


@pytest.mark.parametrize("empty", [(0,), (1, 2), (3,)])
def test_images_without_detections_first_in_a_row_or_last_break_the_chain(empty):
    """A capture that starts dark, or loses the animal for two images, or ends dark: the
    images with detections are still chosen among (here the last one's lower objective
    wins), the empty ones keep index 0."""
    run = [_cands([10.0 + k], [-10.0 - k]) for k in range(4)]
    run[-1] = [Candidate(np.array([13.0]), 0.5, 0.5), Candidate(np.array([-13.0]), 0.01, 0.01)]
    for k in empty:
        run[k] = []
    chosen = choose_candidates(run)
    assert [chosen[k] for k in empty] == [0] * len(empty)
    if 3 not in empty:
        assert chosen[3] == 1


def test_records_keep_the_alternatives():
    fit = ImageFit(4, np.array([1.0, 2.0]), 0.1, 0.1, 1, Status.OK, 500, (4,),
                   (Candidate(np.array([3.0, np.nan]), 0.2, 0.15),))
    back = ImageFit.from_record(fit.to_record())
    assert back.to_record() == fit.to_record()
    assert back.alternatives[0].objective == 0.15 and np.isnan(back.alternatives[0].dofs[1])
    witness = replace(fit, alternatives=(Candidate(np.array([3.0, 2.0]), 0.2, 0.15, minimum=False),))
    assert ImageFit.from_record(witness.to_record()).alternatives[0].minimum is False


def test_the_choice_by_continuity_takes_minima_not_witnesses(locust):
    """The middle image's alternative lies on its neighbours' posture, but as a witness that
    the image does not determine a DOF (a point on a flat valley at a set step, not a
    minimum): the middle image keeps its fit, and the witness stays its alternative. A
    minimum there would be taken."""
    model = locust[0]
    q = np.array([160.0, 15.0, 3.0, 20.0, 80.0])

    def image(k: int, dofs: np.ndarray, *alternatives: Candidate) -> ImageFit:
        return ImageFit(k, dofs, 0.5, 0.5, 1, Status.OK, 0, (4, 4), alternatives)

    moved = q + np.array([0.0, 0.0, 0.0, 0.0, 20.0])
    for minimum, chosen in ((False, moved), (True, q)):
        middle = image(1, moved, Candidate(q.copy(), 0.5, 0.55, minimum=minimum))
        fits = finish_sequence(Histograms.uniform(model), [image(0, q), middle, image(2, q)],
                               model=model, params=FitParams()).fits
        np.testing.assert_array_equal(fits[1].dofs, chosen)
        assert fits[1].alternative_deg(model.rotational) == pytest.approx(20.0)


def test_a_side_view_sequence_entering_the_ambiguous_range_stays_on_its_branch(locust):
    """phi starts at 130 (mirror out of range), then moves into 140..220 where the side
    view cannot tell the leg from its mirror: continuity keeps the true branch."""
    model, _, side = locust
    t = np.linspace(0.0, 1.0, 30)
    truth = np.column_stack([130 + 40 * t, 20 - 10 * t, 2 + 0 * t, 10 + 20 * t, 60 + 40 * t])
    images = [_exact(model, side, q) for q in truth]
    free = FitParams(choose_by_continuity=False)
    fitted = np.array([f.dofs for f in fit_sequence(
        images, model=model, rig=side, histograms=Histograms.uniform(model), params=FitParams(),
        seed=3).fits])
    assert np.abs(fitted - truth).max() < 1.0
    alone = fit_sequence(images, model=model, rig=side, histograms=Histograms.uniform(model),
                         params=free, seed=3)
    ambiguous = [f for f in alone.fits if f.alternatives]
    assert len(ambiguous) >= 20  # without the choice, each image is a coin toss between two


def test_the_choice_across_a_chunk_border_is_the_same_in_one_process_or_two(locust):
    """Candidates are kept per image; the choice by continuity is a pass after the merge, over
    the whole sequence: chunks fitted in two processes choose what one process chooses."""
    model, _, side = locust
    t = np.linspace(0.0, 1.0, 16)
    truth = np.column_stack([150 + 40 * t, 20 - 10 * t, 2 + 0 * t, 10 + 20 * t, 60 + 40 * t])
    images = [_exact(model, side, q) for q in truth]
    kwargs = dict(model=model, rig=side, histograms=Histograms.uniform(model), params=FitParams(),
                  seed=5, chunk_size=8)
    here = fit_sequence(images, **kwargs)
    with ProcessPoolExecutor(max_workers=2) as pool:
        there = fit_sequence(images, map_chunks=pool.map, **kwargs)
    assert sum(bool(f.alternatives) for f in here.fits[6:10]) >= 2  # ambiguous at the border
    for got, want in zip(there.fits, here.fits, strict=True):
        np.testing.assert_array_equal(got.dofs, want.dofs)
        assert [c.objective for c in got.alternatives] == [c.objective for c in want.alternatives]
    chosen = np.array([f.dofs for f in here.fits])  # the whole run is ambiguous: either
    assert np.abs(np.diff(chosen, axis=0)).max() < 5.0  # branch, but one branch throughout
