"""Whole animals: the tree's decomposition into parts (nested where a branch splits again), and
the fit part by part."""

from __future__ import annotations

import itertools
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from tree_subjects import (
    FREE_ROOT,
    angle_errors,
    backbone,
    detections,
    insect,
    movement,
    ring_rig,
    tail,
    vertebrate,
)

from core import _kernels
from core.claims import two_sided_error
from core.error import Detections
from core.examples import EXAMPLES
from core.fit import FitParams
from core.histogram import Histograms
from core.model import KinematicModel
from core.rig import Rig
from core.sequence import fit_sequence
from core.tree import MAX_PART_DOFS, SEGMENT_DOFS, _dof_joints, _name, _subtrees
from core.treefit import _rigid_trunk, search_floor

BENCH = Path(__file__).resolve().parents[2] / "bench" / "subjects"

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


@pytest.mark.parametrize("legs", [0, 2], ids=["alone", "beside two legs"])
def test_a_long_chain_is_cut_into_segments_each_hanging_from_the_one_above(legs):
    """A tail of 12 joints (24 DOFs, a marker at each one's end): segments of
    SEGMENT_DOFS DOFs, each a run of the chain's joints from where the one above ends, with
    the markers of its joints and the one at the origin of the joint below its end; every
    tail marker in one segment."""
    model = tail(12, legs=legs)
    segments = [p for p in model.tree.parts if p.name.startswith("t")]
    assert [len(p.dofs) for p in segments] == [SEGMENT_DOFS] * (24 // SEGMENT_DOFS)
    tail_markers = [m for m, marker in enumerate(model.markers) if marker.name.startswith("tail")]
    owned = np.concatenate([p.markers for p in segments])
    assert sorted(owned.tolist()) == tail_markers
    for above, below in itertools.pairwise(segments):
        assert below.base == above.joints[-1]
    legs_parts = [p.name for p in model.tree.parts if not p.name.startswith("t")]
    assert legs_parts == [f"leg{k}_coxa" for k in range(legs)]


def test_a_backbone_of_three_way_joints_is_cut_into_segments_of_two_vertebrae():
    """Eight vertebrae of 3 DOFs (24), two markers off the axis of each: segments of two
    vertebrae (6 DOFs, 4 markers), each fixed by its markers."""
    tree = backbone(8).tree
    assert [(len(p.dofs), len(p.markers)) for p in tree.parts] == [(6, 4)] * 4


def test_a_chain_of_hinges_is_cut_into_runs_of_four():
    """Twenty 1-DOF joints, a marker at each one's end. Along a chain of equal links the least
    singular value falls as the run grows (1.0, 0.21, 0.11, 0.073 for one to four hinges
    here); held to the plain threshold (0.1), no run of four passed, and the chain stayed
    one part of 20 DOFs."""
    assert [len(p.dofs) for p in tail(20, axes="z").tree.parts] == [SEGMENT_DOFS] * (20 // SEGMENT_DOFS)


def test_a_long_spine_is_cut_into_segments_and_the_arms_hang_from_its_last_vertebra():
    """Legs on the pelvis, eight vertebrae of 3 DOFs (24), arms on the last: the spine, the
    arms' own trunk, is cut into segments of two vertebrae, and the arms hang from the last."""
    model = backbone(8, limbs=True)
    parts = {p.name: p for p in model.tree.parts}
    assert [p.name for p in model.tree.parts] == ["leg0_coxa", "leg1_coxa", "v0", "v2", "v4", "v6",
                                                  "arm0_coxa", "arm1_coxa"]
    assert [len(parts[v].dofs) for v in ("v0", "v2", "v4", "v6")] == [6, 6, 6, 6]
    assert _name(model, parts["arm0_coxa"].base) == _name(model, parts["arm1_coxa"].base) == "v7"
    assert _name(model, parts["v2"].base) == "v1"


def test_a_spine_of_four_vertebrae_carrying_arms_is_one_part_fixed_by_its_markers():
    """Four vertebrae (12 DOFs) are not cut, but their eight markers fix them as a run (each
    vertebra's own two): one part, the arms after it, not one part of 22 DOFs."""
    assert [len(p.dofs) for p in backbone(4, limbs=True).tree.parts] == [5, 5, 12, 5, 5]


def test_a_chain_of_no_more_than_max_part_dofs_stays_one_part():
    assert len(tail(MAX_PART_DOFS // 2).dofs) == MAX_PART_DOFS
    assert tail(MAX_PART_DOFS // 2).tree is None
    assert [len(p.dofs) for p in tail(MAX_PART_DOFS // 2, legs=2).tree.parts] == [MAX_PART_DOFS, 5, 5]


@pytest.mark.parametrize("model", [insect(legs=3), insect(legs=2, root_dofs=FREE_ROOT),
                                   *(KinematicModel.from_xml(BENCH / n / "model.xml")
                                     for n in ("hexapod", "biped"))],
                         ids=["insect", "free", "hexapod", "biped"])
def test_a_tree_that_splits_once_is_a_trunk_and_whole_subtrees(model):
    """One level, as before nesting: the trunk, then every subtree hanging from the first
    split whole, all with that split as their base; no branch's chain is split further."""
    tree, below = model.tree, _subtrees(model.arrays.parent)
    split = tree.branches[0].base
    assert all(p.base == split for p in tree.branches)
    tops = [int(p.joints[0]) for p in tree.branches]
    assert [int(model.arrays.parent[t]) for t in tops] == [split] * len(tops)
    for part, top in zip(tree.branches, tops, strict=True):
        np.testing.assert_array_equal(part.joints, np.flatnonzero(below[top]))
        np.testing.assert_array_equal(part.flips, 1 + np.flatnonzero((part.kin.rot_dof[1:] >= 0).any(axis=1)))
    rest = np.flatnonzero(~below[tops].any(axis=0))  # the trunk: every joint in no branch
    if tree.trunk is not None:
        np.testing.assert_array_equal(tree.trunk.joints, rest)
    else:
        assert not np.isin(_dof_joints(model), rest).any()  # a trunk without DOFs
    assert len(np.concatenate([p.dofs for p in tree.parts])) == len(model.dofs)


def test_a_branch_that_splits_again_is_its_own_trunk_then_its_sub_branches():
    """The spine (3 rotations, 2 markers not collinear with its pivot) is fitted given the
    pelvis, then each arm given the spine's end; parents come before children."""
    model = vertebrate()
    tree = model.tree
    assert tree.trunk is None  # the pelvis has no DOFs
    assert [p.name for p in tree.parts] == ["leg0_coxa", "leg1_coxa", "spine", "arm0_coxa", "arm1_coxa"]
    joint = {j.name: k for k, j in enumerate(model.joints)}  # the file lists parents first
    assert [p.base for p in tree.parts] == [joint["pelvis"]] * 3 + [joint["shoulders"]] * 2
    spine = tree.parts[2]
    assert [model.dofs[d].name for d in spine.dofs] == ["spine_yaw", "spine_roll", "spine_pitch"]
    assert [model.markers[m].name for m in spine.markers] == ["S0", "S1"]
    np.testing.assert_array_equal(spine.joints, [joint["spine"], joint["shoulders"]])
    for k, part in enumerate(tree.parts):
        before = np.concatenate([[joint["pelvis"]], *(p.joints for p in tree.parts[:k])])
        assert part.base in before
    every = np.sort(np.concatenate([p.dofs for p in tree.parts]))
    np.testing.assert_array_equal(every, np.arange(len(model.dofs)))


@pytest.mark.parametrize("spine_markers", [((12.0, 0.0, 1.0),), ((12.0, 0.0, 1.0), (6.0, 0.0, 0.5))],
                         ids=["one marker", "collinear with the pivot"])
def test_a_branch_whose_own_trunk_its_markers_cannot_fix_stays_whole(spine_markers):
    """A spine that rotates three ways is not fixed by one marker, nor by two on a line
    through its pivot (a twist about that line moves neither): spine and arms stay one branch."""
    model = vertebrate(spine_markers=spine_markers)
    assert [p.name for p in model.tree.parts] == ["leg0_coxa", "leg1_coxa", "spine"]
    assert len(model.tree.parts[2].dofs) == 3 + 2 * 5


def test_a_free_root_with_a_nested_branch_is_fitted_first():
    model = vertebrate(root_dofs=FREE_ROOT)
    assert [p.name for p in model.tree.parts] == ["pelvis", "leg0_coxa", "leg1_coxa", "spine",
                                                  "arm0_coxa", "arm1_coxa"]


def test_the_search_floor_is_the_smallest_part_eps_or_eps_for_a_chain():
    """A part stops at ε (1 px) per 4 of its marker projections into the views with
    detections; markers on a trunk without DOFs belong to no part. Below the smallest
    part's ε every part is within its own."""
    params = FitParams()
    free = insect(legs=2, root_dofs=FREE_ROOT)  # trunk 3 markers + 2 legs x 4
    assert search_floor(free, params, 3) == pytest.approx(3 * 3 / 4)
    assert search_floor(free, params, 2) == pytest.approx(3 * 2 / 4)
    assert search_floor(insect(legs=2), params, 3) == pytest.approx(4 * 3 / 4)
    wider = FitParams(anneal=replace(params.anneal, eps=2.0))
    assert search_floor(free, wider, 3) == pytest.approx(2.0 * 3 * 3 / 4)
    chain = KinematicModel.from_xml(EXAMPLES / "locust_hind_leg" / "model.xml")
    assert search_floor(chain, params, 2) == search_floor(chain, params, 6) == params.anneal.eps
    assert search_floor(chain, wider, 2) == 2.0


@pytest.mark.parametrize("model", [insect(legs=3, root_dofs=FREE_ROOT), vertebrate(root_dofs=FREE_ROOT),
                                   tail(12, legs=2), backbone(8, limbs=True)],
                         ids=["insect", "nested", "tail", "backbone"])
def test_a_part_posed_at_its_base_puts_its_markers_where_the_whole_model_does(model):
    """The part's arrays, with its base at the frame the whole posture gives it, are the
    model's own kinematics."""
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


@pytest.mark.parametrize("root_dofs", ["", FREE_ROOT], ids=["fixed pelvis", "free pelvis"])
def test_a_tree_that_splits_twice_fits_part_by_part(root_dofs):
    """Spine given the pelvis, arms given the spine: every DOF within a degree (the arms'
    markers are 4 mm apart, 0.9 px at 200 mm), translations within 0.05 mm."""
    model, rig = vertebrate(root_dofs=root_dofs), ring_rig(3, distance=200.0)
    truth = movement(model, 12, seed=1)
    fitted, fits = _fit(model, rig, truth)
    err = angle_errors(fitted, truth)
    assert err[:, ~model.rotational].max(initial=0.0) < 0.05
    assert err[:, model.rotational].max() < 1.0
    assert all(f.status.value == "ok" for f in fits)


def test_a_long_chain_fits_segment_by_segment():
    """A tail of 12 joints (24 DOFs) in six segments: every DOF within a degree."""
    model, rig = tail(12), ring_rig(3, distance=200.0)
    truth = movement(model, 12, seed=1)
    fitted, fits = _fit(model, rig, truth)
    assert angle_errors(fitted, truth).max() < 1.0
    assert all(f.status.value == "ok" for f in fits)


def test_a_nested_tree_fits_the_same_in_two_processes_as_in_one():
    model, rig = vertebrate(root_dofs=FREE_ROOT), ring_rig(3, distance=200.0)
    images = detections(model, rig, movement(model, 10, seed=2))
    kwargs = dict(model=model, rig=rig, histograms=Histograms.uniform(model), params=FitParams(),
                  seed=0, chunk_size=5)
    here = fit_sequence(images, **kwargs)
    with ProcessPoolExecutor(max_workers=2) as pool:
        there = fit_sequence(images, map_chunks=pool.map, **kwargs)
    for got, want in zip(there.fits, here.fits, strict=True):
        np.testing.assert_array_equal(got.dofs, want.dofs)
        assert got.iterations == want.iterations


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
    off, every = np.zeros((3, 2)), np.ones(len(det.points), dtype=bool)
    none = ~every
    # the blobs' side: the error over every blob less the markers' side alone
    unexplained = [two_sided_error(p, det, model, rig, off, every, 5.0)
                   - two_sided_error(p, det, model, rig, off, none, 5.0) for p in (q, stolen)]
    assert unexplained[0] == pytest.approx(0.0, abs=1e-9)
    assert unexplained[1] > 0.5 * 5.0 * len(a.markers) * len(rig.views)


def test_a_leg_with_hidden_markers_costs_less_two_sided_than_the_same_leg_on_its_neighbours_blobs():
    """Two views, the first leg's claw hidden from one and its tibia from the other (the
    occluded rat's ankle and toe): each is charged at most the cap, as a blob no marker
    explains is. Charged its distance to the nearest blob instead (tens of pixels), the right
    leg cost more than the leg posed on its neighbour's blobs, and the fit took that one (the
    rat's leg 45 deg off, docs/BENCH_SUBJECTS.md)."""
    model = insect(legs=2, attach=[(6.0, 3.0), (-6.0, 3.0)])
    rig, cap = ring_rig(2), 5.0
    q = movement(model, 1, seed=1)[0]
    a, b = model.tree.branches
    tibia, claw = a.markers[2], a.markers[3]
    proj = rig.project(model.marker_positions(q))
    det = Detections.from_views([np.delete(proj[0], claw, axis=0), np.delete(proj[1], tibia, axis=0)])
    for v, hidden in ((0, claw), (1, tibia)):  # hidden farther than the cap from every blob
        assert np.linalg.norm(det.view(v) - proj[v, hidden], axis=1).min() > 2 * cap
    stolen = q.copy()
    stolen[a.dofs] = _onto(model, rig, q, a, b)
    off, blobs = np.zeros((2, 2)), np.ones(len(det.points), dtype=bool)
    right, wrong = (two_sided_error(p, det, model, rig, off, blobs, cap) for p in (q, stolen))
    assert right < wrong
    assert right == pytest.approx(2 * cap)


def test_a_trunk_held_rigid_with_its_branches_puts_every_marker_where_the_whole_model_does():
    model = vertebrate(root_dofs=FREE_ROOT)
    q = movement(model, 1, seed=3)[0]
    trunk = model.tree.trunk
    kin = _rigid_trunk(q, model, trunk)
    got = _kernels.marker_positions_many(np.ascontiguousarray(q[trunk.dofs][None]), kin)[0]
    others = np.setdiff1d(np.arange(len(model.markers)), trunk.markers)
    np.testing.assert_allclose(got, model.marker_positions(q)[np.concatenate([trunk.markers, others])],
                               atol=1e-9)


@pytest.mark.parametrize("seed", [0, 2])
def test_a_trunk_whose_own_markers_are_hidden_is_placed_by_its_legs(seed):
    """Two of the thorax's three markers hidden in every view from the fourth image on: its
    own objective charges them the nearest blob, a leg's, and is lower at a wrong thorax that
    puts them there (on main the thorax ends 15-55 deg off). Judged by the whole model (the
    legs held, their proximal markers on their blobs), it stays within a degree."""
    model, rig = insect(legs=4, root_dofs=FREE_ROOT), ring_rig(3, distance=200.0)
    names = [m.name for m in model.markers]
    hide = [names.index("T0"), names.index("T1")]
    truth = movement(model, 10, seed=seed)
    proj = rig.project(model.marker_positions(truth))
    images = [Detections.from_views([np.delete(p, hide, axis=0) if t >= 3 else p for p in proj[t]])
              for t in range(len(truth))]
    result = fit_sequence(images, model=model, rig=rig, histograms=Histograms.uniform(model),
                          params=FitParams(), seed=0)
    err = angle_errors(np.array([f.dofs for f in result.fits]), truth)
    trunk = model.tree.trunk.dofs
    assert err[:, trunk][:, model.rotational[trunk]].max() < 1.0
    assert err[:, model.rotational].max() < 2.0


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
