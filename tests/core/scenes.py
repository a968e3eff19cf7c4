"""Detections of known postures of the locust example, for the tests of the fitting modules."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.anneal import AnnealParams
from core.error import Detections
from core.model import KinematicModel
from core.rig import Rig

EXAMPLE = Path(__file__).parents[2] / "examples" / "locust_hind_leg"
FAST = AnnealParams(n_end=6000, n_l=600, n_tau=300)


def detections(model: KinematicModel, rig: Rig, postures: np.ndarray, noise: float = 0.0,
               seed: int = 0) -> list[Detections]:
    """Every marker's projection in every view of each posture, plus Gaussian noise (px)."""
    proj = rig.project(model.marker_positions(np.atleast_2d(postures)))
    proj = proj + np.random.default_rng(seed).normal(0.0, noise, proj.shape) if noise else proj
    return [Detections.from_views(list(p)) for p in proj]


def postures(model: KinematicModel, n: int, seed: int = 0) -> np.ndarray:
    """``n`` postures drawn uniformly 5 units inside the model's bounds, shape (n, 5)."""
    return np.random.default_rng(seed).uniform(model.lower + 5, model.upper - 5, (n, 5))
