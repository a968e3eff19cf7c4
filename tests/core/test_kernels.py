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
