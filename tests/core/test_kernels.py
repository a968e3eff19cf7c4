"""The numba kernels' small numerical helpers (core._kernels)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("n", [1, 3, 7])
def test_solve_spd_matches_numpy(n):
    from core._kernels import solve_spd

    rng = np.random.default_rng(n)
    m = rng.normal(size=(n, n))
    a, b = m @ m.T + n * np.eye(n), rng.normal(size=n)
    np.testing.assert_allclose(solve_spd(a, b), np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)



def test_refit_unseen_leaves_out_every_lost_marker_of_a_view():
    """Two of a view's four markers hidden (occluded), each over the penalty from the nearest
    other blob: the refit after an attempt leaves both out, so the true posture stays put,
    charged the penalty twice. Leaving out only the view's worst one let the other pull
    the posture towards a visible marker's blob (the occluded whole-animal images of
    docs/BENCH_SUBJECTS.md)."""
    from scenes import dots_model, pixel_rig

    from core import _kernels
    from core.error import Detections, view_offsets

    model = dots_model((0.0, 0.0), (12.0, 0.0), (0.0, 12.0), (12.0, 12.0))
    rig = pixel_rig(None)
    truth = np.array([50.0, 40.0])
    seen = rig.project(model.marker_positions(truth[None]))[0, 0, :2]  # m2 and m3 hidden
    det = Detections.from_views([seen])
    image = _kernels.Image.of(det.kernel_points, det.start, view_offsets(None, rig),
                              penalty=5.0, fuse_px=0.0)
    q = truth.copy()
    objective = _kernels._refit_unseen(q, np.inf, _kernels.Bounds(model.lower, model.upper),
                                       model.arrays, rig.arrays, image, 1.0)
    np.testing.assert_allclose(q, truth, atol=1e-6)
    assert objective == pytest.approx(10.0, abs=1e-6)


def test_world_jacobian_matches_central_differences():
    """The exact marker Jacobian of refine's inverse kinematics: a translating, turning root,
    rest rotations and every Euler axis, at a posture drawn through the ranges."""
    from tree_subjects import FREE_ROOT, vertebrate

    from core import _kernels

    model = vertebrate(FREE_ROOT)
    kin, rng = model.arrays, np.random.default_rng(3)
    q = model.lower + rng.random(len(model.dofs)) * (model.upper - model.lower)
    fr, sc = np.empty(_kernels.FRAME * len(kin.parent)), np.empty(2 * len(q))
    world, jac = np.empty((len(kin.marker_joint), 3)), np.empty((len(kin.marker_joint), 3, len(q)))
    _kernels.joint_frames(q, kin, fr, sc)
    _kernels.world_markers(fr, kin, world)
    _kernels.world_jacobian(fr, sc, kin, world, jac)
    h, numeric = 1e-6, np.empty_like(jac)
    for i in range(len(q)):
        step = np.zeros(len(q))
        step[i] = h
        numeric[:, :, i] = (model.marker_positions((q + step)[None])[0]
                            - model.marker_positions((q - step)[None])[0]) / (2 * h)
    assert np.abs(numeric).max() > 0.1
    np.testing.assert_allclose(jac, numeric, atol=1e-7)


def test_image_jacobian_matches_central_differences_through_distortion_and_merges():
    """refine's image-mode Jacobian: world Jacobian through distorted pinhole projections, and
    in view 0 each marker merged with those within the assignment's level of it."""
    from tree_subjects import FREE_ROOT, ring_rig, vertebrate

    from core import _kernels

    model, rig = vertebrate(FREE_ROOT), ring_rig(3, dist=(-0.3, 0.1, 0.002, -0.001, 0.0))
    kin, views, rng = model.arrays, rig.arrays, np.random.default_rng(4)
    q = model.lower + rng.random(len(model.dofs)) * (model.upper - model.lower)
    raw = rig.project(model.marker_positions(q[None])[0])  # (V, M, 2)
    V, M, D = raw.shape[0], raw.shape[1], len(q)
    level = np.full(V, -1.0)
    level[0] = 25.0**2
    chosen = _kernels.Assignment(np.ones(V * M, dtype=bool), np.zeros(V * M, dtype=np.int64),
                                 level, raw)
    jac = np.empty((V * M, 2, D))
    work = _kernels.workspace(kin, views, D, 1)
    _kernels.joint_frames(q, kin, work.frames, work.sincos)
    _kernels.world_markers(work.frames, kin, work.world)
    _kernels._jacobian(kin, views, _kernels.NO_TARGETS, work, chosen, np.empty((M, 3, D)),
                       np.empty((V, M, 2, 3)), np.empty((M, 2, D)), jac)
    near = np.sum((raw[0, :, None] - raw[0, None]) ** 2, axis=2) <= level[0]  # (M, M)
    assert near.sum() > M  # some markers merge in view 0

    def merged(p: np.ndarray) -> np.ndarray:
        proj = rig.project(model.marker_positions(p[None])[0])
        proj[0] = near @ proj[0] / near.sum(axis=1, keepdims=True)
        return proj.reshape(V * M, 2)

    h, numeric = 1e-5, np.empty_like(jac)
    for i in range(D):
        step = np.zeros(D)
        step[i] = h
        numeric[:, :, i] = (merged(q + step) - merged(q - step)) / (2 * h)
    np.testing.assert_allclose(jac, numeric, atol=1e-4 * np.abs(numeric).max())


def test_inverse_kinematics_leaves_out_markers_whose_target_is_nan():
    """refine in target mode with some targets NaN solves as the model without those markers:
    the beam search of core.epipolar_start poses a branch onto the markers assigned so far."""
    from tree_subjects import insect, ring_rig

    from core import _kernels

    model = insect(legs=1)
    kin, views = model.arrays, ring_rig(1).arrays
    targets = model.marker_positions((model.lower + 0.6 * (model.upper - model.lower))[None])[0]
    targets[[1, 3]] = np.nan
    kept = ~np.isnan(targets[:, 0])
    subset = kin._replace(marker_joint=kin.marker_joint[kept],
                          marker_pos=np.ascontiguousarray(kin.marker_pos[kept]))
    unread = _kernels.Image.of(np.zeros((0, 3)), np.zeros(2, dtype=np.int64), np.zeros((1, 2)),
                               penalty=0.0, fuse_px=0.0)
    bounds = _kernels.Bounds(model.lower, model.upper)
    start = model.lower + 0.4 * (model.upper - model.lower)
    masked = _kernels.refine(start, bounds, kin, views, unread, np.inf, 10, targets)
    apart = _kernels.refine(start, bounds, subset, views, unread, np.inf, 10,
                            np.ascontiguousarray(targets[kept]))
    assert np.abs(masked - start).max() > 1.0
    np.testing.assert_allclose(masked, apart, atol=1e-9)


@pytest.mark.parametrize("projection", [
    {"type": "affine", "matrix": [[3.0, 0.2, 0.1, 360.0], [0.1, -3.0, 0.4, 144.0]]},
    {"type": "matrix", "P": [[800.0, 10.0, 300.0, 5e4], [5.0, 820.0, 250.0, 4e4], [0.1, 0.05, 1.0, 150.0]]},
    {"type": "pinhole", "K": [[900.0, 0.0, 320.0], [0.0, 880.0, 240.0], [0.0, 0.0, 1.0]],
     "dist": [-0.2, 0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005], "rvec": [0.1, -0.2, 0.05],
     "tvec": [1.0, -2.0, 150.0]},
])
def test_projection_jacobians_match_central_differences(projection):
    """Each view kind's derivative of its projection (the rational distortion model too)."""
    import json

    from core import _kernels
    from core.rig import Rig

    rig = Rig.from_json(json.dumps({"views": [{"name": "v", "video": 0, "projection": projection}]}))
    world = np.random.default_rng(5).uniform(-20.0, 20.0, (6, 3))
    out = np.empty((1, 6, 2, 3))
    _kernels.projection_jacobians(world, rig.arrays, out)
    h, numeric = 1e-5, np.empty_like(out)
    for j in range(3):
        step = np.zeros(3)
        step[j] = h
        numeric[..., j] = (rig.project(world + step) - rig.project(world - step)) / (2 * h)
    assert np.abs(numeric).max() > 1.0
    np.testing.assert_allclose(out, numeric, rtol=1e-6, atol=1e-6)
