"""Models, rigs and detections the tests of several core modules share."""

from __future__ import annotations

import numpy as np

from core.anneal import AnnealParams
from core.error import Detections
from core.model import KinematicModel
from core.rig import Rig

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


def dots_model(*offsets: tuple[float, float]) -> KinematicModel:
    """Markers at fixed pixel offsets from a root that translates in x and y."""
    markers = "".join(
        f'<marker name="m{i}" joint="root" x="{x}" y="{y}" z="0"/>'
        for i, (x, y) in enumerate(offsets)
    )
    return KinematicModel.from_xml(
        '<model name="dots" units="px"><joint name="root">'
        '<dof axis="tx" name="tx" min="0" max="128"/><dof axis="ty" name="ty" min="0" max="96"/>'
        f"</joint>{markers}</model>"
    )


def pixel_rig(*rois: list[int] | None) -> Rig:
    """Views with the identity projection (u, v) = (x, y), one per roi."""
    views = [
        {"name": f"v{i}", "projection": {"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]},
         **({"roi": roi} if roi is not None else {})}
        for i, roi in enumerate(rois)
    ]
    return Rig.from_dict({"views": views})
