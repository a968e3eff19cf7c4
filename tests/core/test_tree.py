"""Whole animals: the tree's decomposition into trunk and branches, and the fit part by part."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from tree_subjects import FREE_ROOT, angle_errors, detections, insect, movement, ring_rig

from core import _kernels
from core.examples import EXAMPLES
from core.fit import FitParams
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig
from core.sequence import fit_sequence
from core.treefit import search_floor, two_sided_error

# ---- decomposition ---------------------------------------------------------------------------


@pytest.mark.parametrize("example", ["locust_hind_leg", "stick_insect_front_leg"])
def test_a_single_chain_is_fitted_whole(example):
    assert KinematicModel.from_xml(EXAMPLES / example / "model.xml").tree is None


def test_two_legs_on_a_fixed_root_are_two_branches_without_a_trunk():
    model = insect(legs=2)
    tree = model.tree
    assert tree is not None and tree.trunk is None
    assert [p.name for p in tree.branches] == ["leg0_coxa", "leg1_coxa"]
    for k, part in enumerate(tree.branches):
        assert [model.dofs[d].name for d in part.dofs] == [
            f"leg{k}_{n}" for n in ("yaw", "roll", "pitch", "lev", "knee")]
        assert [model.markers[m].name for m in part.markers] == [
            f"leg{k}_{j}" for j in ("coxa", "femur", "tibia", "claw")]


def test_a_free_root_with_three_markers_is_a_trunk_fitted_first():
    model = insect(legs=2, root_dofs=FREE_ROOT)
    trunk = model.tree.trunk
    assert [model.dofs[d].name for d in trunk.dofs] == ["tx", "ty", "tz", "pitch", "roll", "heading"]
    assert [model.markers[m].name for m in trunk.markers] == ["T0", "T1", "T2"]


def test_a_free_root_its_markers_cannot_fix_makes_the_tree_one_part():
    assert insect(legs=2, root_dofs=FREE_ROOT, thorax_markers=2).tree is None


def test_the_search_floor_is_the_sum_of_the_parts_eps_or_eps_for_a_chain():
    """A part stops at ε (1 px) per 4 of its marker projections into the views with
    detections; markers on a trunk without DOFs belong to no part."""
    params = FitParams()
    free = insect(legs=2, root_dofs=FREE_ROOT)  # trunk 3 markers + 2 legs x 4
    assert search_floor(free, params, 3) == pytest.approx((3 + 4 + 4) * 3 / 4)
    assert search_floor(free, params, 2) == pytest.approx((3 + 4 + 4) * 2 / 4)
    assert search_floor(insect(legs=2), params, 3) == pytest.approx((4 + 4) * 3 / 4)
    wider = FitParams(anneal=replace(params.anneal, eps=2.0))
    assert search_floor(free, wider, 3) == pytest.approx(2.0 * (3 + 4 + 4) * 3 / 4)
    chain = KinematicModel.from_xml(EXAMPLES / "locust_hind_leg" / "model.xml")
    assert search_floor(chain, params, 2) == search_floor(chain, params, 6) == params.anneal.eps
    assert search_floor(chain, wider, 2) == 2.0


def test_a_part_posed_at_its_base_puts_its_markers_where_the_whole_model_does():
    """The part's arrays, with its base at the trunk's frame, are the model's own kinematics."""
    model = insect(legs=3, root_dofs=FREE_ROOT)
    q = movement(model, 7, seed=3)[-1]
    world = model.marker_positions(q)
    J = len(model.joints)
    rot, pos = np.empty((J, 3, 3)), np.empty((J, 3))
    _kernels.forward_kinematics(q, model.arrays, rot, pos)
    for part in model.tree.parts:
        kin = part.at(rot[part.base], pos[part.base]) if part.base >= 0 else part.kin
        got = _kernels.marker_positions_many(np.ascontiguousarray(q[part.dofs][None]), kin)[0]
        np.testing.assert_allclose(got, world[part.markers], atol=1e-9)


# ---- fitting part by part ---------------------------------------------------------------------


def _fit(model: KinematicModel, rig: Rig, truth: np.ndarray, **params) -> tuple[np.ndarray, list]:
    result = fit_sequence(detections(model, rig, truth), model=model, rig=rig,
                          histograms=Histograms.uniform(model), params=FitParams(**params), seed=0)
    return np.array([f.dofs for f in result.fits]), result.fits


def test_two_branches_sharing_a_fixed_root_fit_to_a_fraction_of_a_degree():
    model, rig = insect(legs=2), ring_rig(3)
    truth = movement(model, 12, seed=1)
    fitted, fits = _fit(model, rig, truth)
    assert angle_errors(fitted, truth).max() < 0.5
    assert all(f.status.value == "ok" for f in fits)


def test_a_root_with_translations_is_found_before_its_legs():
    model, rig = insect(legs=2, root_dofs=FREE_ROOT), ring_rig(3, distance=200.0)
    truth = movement(model, 12, seed=2)
    fitted, _ = _fit(model, rig, truth)
    err = angle_errors(fitted, truth)
    assert err[:, :3].max() < 0.05  # mm
    assert err[:, 3:].max() < 1.0


def test_a_leg_on_its_neighbours_blobs_costs_more_two_sided_than_the_truth():
    """Eq. 5 never charges the blobs a leg leaves when it moves onto its neighbour's (both
    legs then explain the same blobs); the two-sided error charges them."""
    model = insect(legs=2, attach=[(6.0, 3.0), (-6.0, 3.0)])  # two legs on one side
    rig = ring_rig(3)
    q = movement(model, 1, seed=4)[0]
    det = detections(model, rig, q, noise_px=0.0)[0]
    stolen = q.copy()
    a, b = model.tree.branches
    stolen[a.dofs] = _onto(model, rig, q, a, b)
    off, blobs = np.zeros((3, 2)), np.ones(len(det.points), dtype=bool)
    image = _kernels.Image.of(det.kernel_points, det.start, off, penalty=5.0, fuse_px=0.0)
    plain = [_kernels.posture_error(p, model.arrays, rig.arrays, image) for p in (q, stolen)]
    two_sided = [two_sided_error(p, det, model, rig, off, blobs, 5.0) for p in (q, stolen)]
    left_unexplained = (two_sided[1] - two_sided[0]) - (plain[1] - plain[0])
    assert left_unexplained > 0.5 * 5.0 * len(a.markers) * len(rig.views)


def _onto(model, rig, q, thief, victim) -> np.ndarray:
    """Leg ``thief``'s DOFs putting its markers closest to where ``victim``'s markers are."""
    targets = model.marker_positions(q)[victim.markers]
    best, best_cost = None, np.inf
    rng = np.random.default_rng(0)
    for _ in range(4000):
        trial = q.copy()
        trial[thief.dofs] = rng.uniform(model.lower[thief.dofs], model.upper[thief.dofs])
        cost = np.linalg.norm(model.marker_positions(trial)[thief.markers] - targets, axis=1).sum()
        if cost < best_cost:
            best, best_cost = trial[thief.dofs], cost
    return best
