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


def _two_hidden_scene():
    """A 4-marker dots model whose view shows m0 and m1 (m2, m3 hidden) at ``truth``, and
    three ghost blobs 3 px around where m0–m2 project at ``other``: (model, rig, detections,
    truth, other). At ``other`` three markers are 3 px off and m3 9.5 px; at ``truth`` m2 and
    m3 are 12–14 px from the nearest blob."""
    from scenes import dots_model, pixel_rig

    from core.error import Detections

    model = dots_model((0.0, 0.0), (12.0, 0.0), (0.0, 12.0), (14.0, 12.0))
    rig = pixel_rig(None)
    truth, other = np.array([40.0, 20.0]), np.array([40.0, 50.0])

    def project(q: np.ndarray) -> np.ndarray:
        return rig.project(model.marker_positions(q[None]))[0, 0]

    turns = np.radians([0.0, 120.0, 240.0])
    ghosts = project(other)[:3] + 3.0 * np.stack([np.cos(turns), np.sin(turns)], axis=1)
    det = Detections.from_views([np.vstack([project(truth)[:2], ghosts])])
    return model, rig, det, truth, other


def test_every_marker_beyond_the_penalty_is_charged_the_penalty():
    """The restarts' objective (``lost_px`` = penalty) of the true posture with two markers of
    a view hidden: the seen markers' Eq. 5 plus twice the penalty, not the second hidden
    marker's distance to another blob; and it ranks the truth below a posture that puts three
    markers 3 px from ghosts (which charging only each view's worst marker ranked lower)."""
    from core import _kernels
    from core.error import view_offsets

    model, rig, det, truth, other = _two_hidden_scene()
    image = _kernels.Image.of(det.kernel_points, det.start, view_offsets(None, rig), penalty=5.0,
                              fuse_px=4.0, lost_px=5.0)

    def objective(q: np.ndarray) -> float:
        return float(_kernels.posture_error(q, model.arrays, rig.arrays, image))

    assert objective(truth) == pytest.approx(0.0 + 2 * 5.0, abs=1e-9)
    assert objective(other) == pytest.approx(3 * 3.0 + 5.0, abs=1e-9)
    assert objective(truth) < objective(other)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_fit_with_two_hidden_markers_in_a_view_prefers_the_truth(seed):
    """The scene above fitted (fusion on, so restarts search the lost-marker objective): the
    fit ends at the truth, charged twice the penalty."""
    from core.fit import FitParams
    from core.histogram import Histograms
    from core.sequence import fit_chunk

    model, rig, det, truth, _ = _two_hidden_scene()
    fit = fit_chunk([det], model=model, rig=rig, histograms=Histograms.uniform(model),
                    params=FitParams(fusion_px=4.0, empty_view_penalty_px=5.0), seed=seed).fits[0]
    np.testing.assert_allclose(fit.dofs, truth, atol=1e-3)
    assert fit.objective == pytest.approx(10.0, abs=1e-6)
