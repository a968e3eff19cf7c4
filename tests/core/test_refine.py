"""Levenberg–Marquardt refinement (core.refine): sub-pixel from a nearby posture, within the bounds."""

from __future__ import annotations

import numpy as np
from scenes import detections

from bench.animals import fit_params, render_and_detect
from bench.subjects import load
from core import _kernels
from core.error import Detections, view_error, view_offsets
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


def _residuals(q, det, model, rig, chosen, fuse_px=0.0):
    """``_kernels._residuals`` of posture ``q`` in image mode: (V·M, 2) residuals, and the
    workspace holding the posture's evaluation."""
    image = _kernels.Image.of(det.kernel_points, det.start, view_offsets(None, rig), penalty=5.0,
                              fuse_px=fuse_px)
    work = _kernels.workspace(model.arrays, rig.arrays, len(q), len(det.kernel_points))
    res = np.empty((len(rig.views) * len(model.markers), 2))
    _kernels._residuals(np.ascontiguousarray(q, dtype=float), model.arrays, rig.arrays, image,
                        _kernels.NO_TARGETS, work, res, chosen)
    return res, work


def _assignment(model, rig):
    return _kernels._assignment(len(rig.views) * len(model.markers), len(rig.views), len(model.markers))


def _jacobian(model, rig, work, chosen):
    """refine's Jacobian (V·M, 2, D) at the posture ``work`` holds, under ``chosen``."""
    V, M, D = len(rig.views), len(model.markers), len(model.dofs)
    jac = np.empty((V * M, 2, D))
    _kernels._jacobian(model.arrays, rig.arrays, _kernels.NO_TARGETS, work, chosen, np.empty((M, 3, D)),
                       np.empty((V, M, 2, 3)), np.empty((M, 2, D)), jac)
    return jac


def test_the_jacobian_follows_the_projection_where_the_nearest_detection_switches(locust):
    """A marker between two blobs whose nearest switches when the posture moves by 0.01°:
    chosen again, its residual jumps to the other blob; the Jacobian at the first posture
    moves it with its projection, as a derivative must."""
    model, rig = locust
    q = np.array([160.0, 10.0, 3.0, 20.0, 100.0])
    moved = q.copy()
    moved[3] += 0.01
    p, p_moved = (rig.project(model.marker_positions(x[None]))[0] for x in (q, moved))
    m = int(np.argmax(np.linalg.norm(p_moved[0] - p[0], axis=1)))
    s = float(np.linalg.norm(p_moved[0, m] - p[0, m]))
    d = (p_moved[0, m] - p[0, m]) / s
    behind, ahead = p[0, m] - d, p[0, m] + d * (1.0 + s / 2)  # nearest at q, nearest at moved
    views = [np.vstack([np.delete(p[0], m, axis=0), behind, ahead]), p[1]]
    det = Detections.from_views(views)
    chosen = _assignment(model, rig)
    res, work = _residuals(q, det, model, rig, chosen)
    np.testing.assert_allclose(res[m], p[0, m] - behind)
    np.testing.assert_allclose(res[m] + 0.01 * _jacobian(model, rig, work, chosen)[m, :, 3],
                               p_moved[0, m] - behind, atol=1e-5)
    np.testing.assert_allclose(_residuals(moved, det, model, rig, _assignment(model, rig))[0][m],
                               p_moved[0, m] - ahead)


def test_the_jacobian_keeps_the_merges_of_the_posture_it_linearises_at():
    """The 6-camera hexapod, where thorax and leg markers merge into one blob in some view:
    0.001° from the posture the assignment was made at, the residuals chosen again (the
    merged views included) are the first ones moved along the Jacobian."""
    subject = load("hexapod")
    model, rig = subject.model, subject.rig
    data = render_and_detect(subject, 5, soft=False, ghosts=2, rng=np.random.default_rng(0))
    fuse_px = fit_params(data)[0].fusion_px
    merged_views = 0
    for truth, det in zip(data.truth, data.detections, strict=True):
        chosen = _assignment(model, rig)
        res, work = _residuals(truth, det, model, rig, chosen, fuse_px)
        merged_views += int(np.sum(chosen.level >= 0))
        jac = _jacobian(model, rig, work, chosen)
        for i in np.random.default_rng(1).choice(len(truth), 8, replace=False):
            step = truth.copy()
            step[i] += 1e-3
            again = _residuals(step, det, model, rig, _assignment(model, rig), fuse_px)[0]
            np.testing.assert_allclose(res + 1e-3 * jac[:, :, i], again, atol=1e-6)
    assert merged_views > 0
