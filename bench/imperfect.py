"""A lab's model and calibration as they really are: slightly wrong.

A subject is rendered with its own model and rig; a lab fits with a model measured by hand
(segment lengths and marker placements off by a few per cent) and a rig from a calibration
(each view's reprojection off by a fraction of a pixel to a few pixels). These return such
a model and rig, for ``bench/animals.py --model-error`` and ``--rig-error``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.model import KinematicModel
from core.rig import Rig, View


def measured_model(model: KinematicModel, relative: float,
                   rng: np.random.Generator) -> KinematicModel:
    """``model`` with every joint offset and marker position vector scaled by its own factor
    1 + N(0, ``relative``): segment lengths and marker placements measured with that
    relative error (0.05: 5 %). The DOFs, their ranges and the names are unchanged."""
    def scaled(vector: tuple[float, float, float]) -> tuple[float, float, float]:
        x, y, z = np.asarray(vector, dtype=float) * (1.0 + relative * rng.standard_normal())
        return float(x), float(y), float(z)

    joints = tuple(replace(j, offset=scaled(j.offset)) if j.parent is not None else j
                   for j in model.joints)
    markers = tuple(replace(m, position=scaled(m.position)) for m in model.markers)
    return replace(model, joints=joints, markers=markers)


def calibrated_rig(rig: Rig, shift_px: float, rng: np.random.Generator) -> Rig:
    """``rig`` with every view's image shifted by ``shift_px`` pixels in a random direction
    (a calibration's principal-point or pose error: views that no longer agree exactly on
    where a 3D point is)."""
    return Rig(tuple(_shifted(view, shift_px * _direction(rng)) for view in rig.views))


def _direction(rng: np.random.Generator) -> np.ndarray:
    angle = rng.uniform(0.0, 2.0 * np.pi)
    return np.array([np.cos(angle), np.sin(angle)])


def _shifted(view: View, shift: np.ndarray) -> View:
    """``view`` whose projection lands ``shift`` (du, dv) pixels away."""
    p = dict(view.projection)
    if p["type"] == "affine":
        matrix = np.array(p["matrix"], dtype=float)
        matrix[:, 3] += shift
        p["matrix"] = matrix.tolist()
    elif p["type"] == "matrix":  # u = (P0 · X) / (P2 · X): adding s·P2 to P0 adds s to u
        P = np.array(p["P"], dtype=float)
        P[:2] += np.outer(shift, P[2])
        p["P"] = P.tolist()
    else:  # pinhole: the principal point moves the distorted image as a whole
        K = np.array(p["K"], dtype=float)
        K[:2, 2] += shift
        p["K"] = K.tolist()
    return replace(view, projection=p)
