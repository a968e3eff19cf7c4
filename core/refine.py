"""Local refinement of the posture Simulated Annealing found.

SA with Table 1 parameters ends with steps of a degree or two, i.e. a few
pixels on a long segment (the paper's 2.9 px mean view error). A bounded
Levenberg–Marquardt on the same nearest-detection residuals polishes that
basin to sub-pixel consistency. It never replaces SA's global search: it
starts from SA's best posture, re-chooses nearest detections at every step
(no marker labels), stays inside the DOF ranges, and its result is kept only
if its Eq. 5 error is not worse (see ``core.fit``).
"""

from __future__ import annotations

import numpy as np

from core import _kernels
from core.error import (
    DEFAULT_EMPTY_VIEW_PENALTY_PX,
    Detections,
    check_fusion,
    check_views,
    view_offsets,
)
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["refine"]


def refine(
    dofs: np.ndarray,
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    offsets: np.ndarray | None = None,
    huber_px: float = 1.0,
    max_iter: int = 50,
    fusion_px: float = 0.0,
    empty_view_penalty_px: float = DEFAULT_EMPTY_VIEW_PENALTY_PX,
) -> np.ndarray:
    """Refine a posture by bounded, robust least squares.

    Parameters
    ----------
    dofs : ndarray of shape (D,), float64, the starting posture (SA's best).
    huber_px : float
        Residuals shorter than this are squared (least squares, efficient for
        detection noise); longer ones count by their length, as in Eq. 5, so a
        fused or missing marker cannot drag the fit. Where one lies beyond it while
        most lie well within, the radius then tightens to 0.1 px
        (``core._kernels.MIN_RADIUS_PX``), for the markers not to give way to it.
    max_iter : int
        Levenberg–Marquardt iterations at most.
    fusion_px : float
        Markers projecting closer than this may be one blob (``core.error``); 0: off.
    empty_view_penalty_px : float
        The charge of a marker the camera does not show: with ``fusion_px`` > 0, a
        marker the objective treats as not seen is left out of the least squares.

    Returns
    -------
    ndarray of shape (D,), float64, the refined posture, inside the DOF ranges.
    """
    if not huber_px > 0:
        raise ValueError(f"huber_px must be positive, got {huber_px}")
    if max_iter < 0:
        raise ValueError(f"max_iter must be non-negative, got {max_iter}")
    check_views(detections, rig)
    q = np.clip(model._check_postures(dofs)[0], model.lower, model.upper)
    image = _kernels.Image.of(detections.kernel_points, detections.start, view_offsets(offsets, rig),
                              penalty=empty_view_penalty_px, fuse_px=check_fusion(fusion_px))
    return _kernels.refine(q, _kernels.Bounds(model.lower, model.upper), model.arrays, rig.arrays, image,
                           float(huber_px), int(max_iter), _kernels.NO_TARGETS)
