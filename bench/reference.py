"""A labelled inverse-kinematics reference: what a pipeline given the marker labels reports.

Issue 13's real capture was judged against inverse kinematics given the labels: for each
image, the posture whose model markers lie nearest, in 3D and in least squares, to the
markers as captured (OpenSim's inverse kinematics with equal marker weights). Under sliding
skin, or with a model measured by hand, that posture is not the truth, and no fit of the
images can recover the truth; the reference says how far the engine's fit is from what a
labelled pipeline with the same model reports.
"""

from __future__ import annotations

import numpy as np

from core.model import KinematicModel

STEP = 1e-5  # forward-difference step of the Jacobian: degrees, or model units
ITERATIONS = 100
DAMPING_LIMIT = 1e12  # Levenberg-Marquardt gives up on a step past this damping


def labelled_ik(model: KinematicModel, markers: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(D,) the posture within the model's ranges whose markers are nearest ``markers``
    ((M, 3), model units, world frame, in the model's marker order) in summed squared 3D
    distance: Levenberg-Marquardt from ``start`` (D,), a forward-difference Jacobian."""
    lower, upper = model.lower, model.upper
    q = np.clip(start, lower, upper)
    r = _residual(model, q[None], markers)[0]
    cost = float(r @ r)
    damping = 1e-3
    for _ in range(ITERATIONS):
        jac = (_residual(model, q + STEP * np.eye(len(q)), markers) - r).T / STEP  # (3M, D)
        normal, gradient = jac.T @ jac, jac.T @ r
        while damping < DAMPING_LIMIT:
            step = np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-12), -gradient)
            q_new = np.clip(q + step, lower, upper)
            r_new = _residual(model, q_new[None], markers)[0]
            if (cost_new := float(r_new @ r_new)) < cost:
                break
            damping *= 4.0
        else:
            return q
        done = cost - cost_new < 1e-12 * max(cost, 1e-300)
        q, r, cost, damping = q_new, r_new, cost_new, damping / 3.0
        if done:
            break
    return q


def labelled_postures(model: KinematicModel, markers: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(T, D): :func:`labelled_ik` of every image's ``markers`` (T, M, 3) from ``starts`` (T, D)."""
    return np.array([labelled_ik(model, m, q) for m, q in zip(markers, starts, strict=True)])


def _residual(model: KinematicModel, postures: np.ndarray, markers: np.ndarray) -> np.ndarray:
    """(N, 3M): the model's markers in ``postures`` (N, D) less ``markers`` (M, 3)."""
    return (model.marker_positions(postures) - markers).reshape(len(postures), -1)
