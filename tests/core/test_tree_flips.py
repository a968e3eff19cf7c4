"""Depth flips of a tree, branch by branch (core.treefit.tree_flip_alternatives)."""

from __future__ import annotations

import numpy as np
import pytest
from tree_subjects import detections, insect, movement, ring_rig, vertebrate

from core.ambiguity import MAX_ALTERNATIVES, Candidate, FlipGeometry, flip_alternatives
from core.error import view_error
from core.fit import flip_geometry
from core.rig import Rig
from core.treefit import tree_flip_alternatives


@pytest.mark.parametrize("seed", [2, 4, 5])
@pytest.mark.parametrize("model", [insect(legs=2), vertebrate()], ids=["insect", "nested"])
def test_branch_by_branch_finds_every_flip_the_whole_model_search_finds(seed, model):
    """One distant camera (nearly orthographic): a leg and its reflection through a plane
    normal to the view image alike. Scoring each leg's flips on its own markers finds
    every alternative that scoring them on the whole model finds (within 0.1°, at an objective
    no higher: the refinement's radius tightens on the residuals it sees, a branch's or the
    whole model's), but those that more alternatives (up to MAX_ALTERNATIVES) of lower
    objective crowd out; in a nested tree, the spine's flips (which carry the arms) are the
    whole model's."""
    rig = Rig(ring_rig(3, distance=3000.0, f=18000.0).views[:1])
    q = movement(model, 1, seed=seed)[0]
    det = detections(model, rig, q, noise_px=0.0)[0]
    error = view_error(q, det, model=model, rig=rig)
    kwargs = dict(model=model, rig=rig, tolerance_px=3.0, fusion_px=0.0, empty_view_penalty_px=5.0,
                  huber_px=1.0)
    whole = flip_alternatives(Candidate(q, error, error), det, geometry=FlipGeometry.of(model, rig), **kwargs)
    by_branch = tree_flip_alternatives(Candidate(q, error, error), det, geometry=flip_geometry(model, rig),
                                       **kwargs)
    assert whole
    for want in whole:
        if len(by_branch) == MAX_ALTERNATIVES and want.objective > by_branch[-1].objective:
            continue  # crowded out by better flips (every subset of a branch's joints is tried)
        assert any(np.abs(got.dofs - want.dofs).max() < 0.1
                   and got.objective <= want.objective + 1e-6 for got in by_branch)
    for got in by_branch:
        moved = [np.abs(got.dofs - q)[p.dofs].max() > 1.0 for p in model.tree.branches]
        assert sum(moved) == 1  # one leg flipped, the other as fitted
        assert got.objective <= error + 3.0
