"""The error function of paper Eq. 5 and the detections it compares against.

``E = Σ_views Σ_markers min_c ‖p_i^k − d_c^k‖``: every projected model marker
is charged the distance to the nearest detected point of its view, so ghost
markers, fused markers and unlabelled detections need no special handling.

A view with no detections at all carries no information about the posture;
it adds a constant ``empty_view_penalty_px`` per model marker (default 5 px),
so that the total stays finite, never NaN, does not steer the search, and an
image that lost a whole view is flagged by the error threshold instead of
being reported as a confident fit.

Marker fusion (``fusion_px`` > 0, about the marker diameter in pixels): model
markers that project closer than ``fusion_px`` are compared as the single blob
a camera shows, at their common centroid. Otherwise the true posture of a
frame with fused markers is not a minimum of Eq. 5, and the fit is pulled
several degrees off. ``fusion_px = 0`` is the paper's Eq. 5 exactly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from core import _kernels
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["DEFAULT_EMPTY_VIEW_PENALTY_PX", "Detections", "view_error"]

DEFAULT_EMPTY_VIEW_PENALTY_PX = 5.0


@dataclass(frozen=True)
class Detections:
    """Detected marker centroids of one image, grouped by view.

    points : ndarray of shape (N, 2), float64, full-frame pixels (u, v).
    start : ndarray of shape (V + 1,), int64; view v owns ``points[start[v]:start[v+1]]``.
    """

    points: np.ndarray
    start: np.ndarray

    @classmethod
    def from_views(cls, views: Sequence[np.ndarray]) -> Detections:
        """Build from one (N_v, 2) array of pixel coordinates per view (N_v may be 0)."""
        arrays = [np.asarray(v, dtype=np.float64).reshape(-1, 2) for v in views]
        for i, a in enumerate(arrays):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"detections of view {i} contain a non-finite coordinate")
        start = np.zeros(len(arrays) + 1, dtype=np.int64)
        start[1:] = np.cumsum([len(a) for a in arrays])
        points = np.concatenate(arrays) if arrays else np.zeros((0, 2))
        return cls(np.ascontiguousarray(points), start)

    @property
    def n_views(self) -> int:
        return len(self.start) - 1

    @property
    def counts(self) -> np.ndarray:
        """(V,) int64: number of detections in each view."""
        return np.diff(self.start)

    def view(self, v: int) -> np.ndarray:
        return self.points[self.start[v] : self.start[v + 1]]


def view_error(
    dofs: np.ndarray,
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    offsets: np.ndarray | None = None,
    empty_view_penalty_px: float = DEFAULT_EMPTY_VIEW_PENALTY_PX,
    fusion_px: float = 0.0,
) -> float:
    """Eq. 5 for one posture, in pixels (with marker fusion when ``fusion_px`` > 0).

    Parameters
    ----------
    dofs : ndarray of shape (D,), float64, model-file order (degrees, model units).
    detections : Detections with one group per rig view.
    offsets : ndarray of shape (V, 2), float64, pixels, optional
        Added to every projection of a view (root tracking, paper §2.1).
    """
    q = model._check_postures(dofs)[0]
    check_views(detections, rig)
    return float(
        _kernels.posture_error(
            q, model.arrays, rig.arrays, view_offsets(offsets, rig), detections.points,
            detections.start, float(empty_view_penalty_px), check_fusion(fusion_px),
        )
    )


def view_offsets(offsets: np.ndarray | None, rig: Rig) -> np.ndarray:
    """(V, 2) float64 per-view pixel offsets, zeros when not given."""
    if offsets is None:
        return np.zeros((len(rig.views), 2))
    off = np.ascontiguousarray(offsets, dtype=np.float64)
    if off.shape != (len(rig.views), 2) or not np.all(np.isfinite(off)):
        raise ValueError(f"offsets must be a finite ({len(rig.views)}, 2) array, got {off.shape}")
    return off


def check_fusion(fusion_px: float) -> float:
    """``fusion_px`` as a float, or ValueError naming it."""
    if not (np.isfinite(fusion_px) and fusion_px >= 0):
        raise ValueError(f"fusion_px must be a non-negative number, got {fusion_px!r}")
    return float(fusion_px)


def check_views(detections: Detections, rig: Rig) -> None:
    if detections.n_views != len(rig.views):
        raise ValueError(
            f"detections have {detections.n_views} views but the rig has {len(rig.views)}"
        )
