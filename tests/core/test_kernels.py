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

