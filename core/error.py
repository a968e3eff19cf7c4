"""The error function of paper Eq. 5 and the detections it compares against.

``E = Σ_views Σ_markers min_c ‖p_i^k − d_c^k‖``: every projected model marker
is charged the distance to the nearest detected point of its view, so ghost
markers, fused markers and unlabelled detections need no special handling.

A view with no detections at all carries no information about the posture;
it adds a constant ``empty_view_penalty_px`` per model marker (default 5 px),
so that the total stays finite, never NaN, does not steer the search, and an
image that lost a whole view is flagged by the error threshold instead of
being reported as a confident fit.

A marker projecting outside its view's region (its roi or its frame, ``core.rig.Rig.regions``)
by more than half its diameter (closer, part of its disc shows) cannot have been detected:
the search charges it the same constant, as a marker the camera lost
(``core._kernels.charged_unseen``). The reported Eq. 5 charges it its nearest
detection, as FORMATS §3 defines ``error_px``; :func:`outside_error` says how much of it that is.

Blobs (``fusion_px`` > 0; :func:`fusion_distance` of the marker diameter): a
camera shows two markers closer than about 1.3 diameters as one blob at their
centroid, and it merges closer pairs first, so every view is read apart and with
the pairs closer than each pair distance below ``fusion_px`` merged (nested
readings), whichever explains it best; and a detection no
marker claims, next to markers that share a blob, is charged (two markers put
on one blob leave it unexplained: the paper's Fig. 9). Otherwise the true
posture of a frame with fused markers is not a minimum, and a wrong one that
collapses two markers onto one blob can be (``core._kernels.blob_error``).
``fusion_px = 0`` is the paper's Eq. 5 exactly; the reported ``error_px`` is
always the plain Eq. 5.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from core import _kernels
from core._kernels import FUSION_DIAMETERS
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["DEFAULT_EMPTY_VIEW_PENALTY_PX", "Detections", "fused_marker_diameter", "fusion_distance",
           "marker_errors", "nearest_detection", "outside_error", "view_error"]

DEFAULT_EMPTY_VIEW_PENALTY_PX = 5.0


def fusion_distance(marker_diameter_px: float) -> float:
    """The ``fusion_px`` for markers of this diameter in pixels.

    >>> fusion_distance(4.0)
    8.0
    """
    return FUSION_DIAMETERS * float(marker_diameter_px)


def fused_marker_diameter(fusion_px: float) -> float:
    """The markers' diameter in pixels whose ``fusion_px`` this is (:func:`fusion_distance`
    inverted): what a fit's settings, which keep the fusion distance, say of its markers.

    >>> fused_marker_diameter(8.0)
    4.0
    """
    return float(fusion_px) / FUSION_DIAMETERS


# A detection this many times the image's median area is large enough to be markers the
# detector merged: one 4 px marker's area (its light over its peak) is 12.4 px², two merged
# more, up to twice that where they just touch.
MERGED_AREA_RATIO = 1.2


@dataclass(frozen=True)
class Detections:
    """Detected marker centroids of one image, grouped by view.

    points : ndarray of shape (N, 2), float64, full-frame pixels (u, v).
    start : ndarray of shape (V + 1,), int64; view v owns ``points[start[v]:start[v+1]]``.
    areas : ndarray of shape (N,), float64, pixels of each detection's region, or None
        when unknown (detections made by hand): then any detection may be merged markers.
    """

    points: np.ndarray
    start: np.ndarray
    areas: np.ndarray | None = None

    @classmethod
    def from_views(
        cls, views: Sequence[np.ndarray], areas: Sequence[np.ndarray] | None = None
    ) -> Detections:
        """Build from one (N_v, 2) array of pixel coordinates per view (N_v may be 0),
        and optionally one (N_v,) array of region areas per view."""
        arrays = [np.asarray(v, dtype=np.float64).reshape(-1, 2) for v in views]
        for i, a in enumerate(arrays):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"detections of view {i} contain a non-finite coordinate")
        start = _group_starts(arrays)
        points = np.concatenate(arrays) if arrays else np.zeros((0, 2))
        flat = None
        if areas is not None:
            flat = np.concatenate([np.asarray(a, dtype=np.float64).reshape(-1) for a in areas])
            if flat.shape != (len(points),):
                raise ValueError(f"{flat.size} areas for {len(points)} detections")
        return cls(np.ascontiguousarray(points), start, flat)

    @classmethod
    def _of_views(cls, points: Sequence[np.ndarray], areas: Sequence[np.ndarray]) -> Detections:
        """:meth:`from_views` without its checks, for detectors whose (N_v, 2) float64
        centroids are finite by construction (a frame's detection is on the hot path)."""
        return cls(np.concatenate(points), _group_starts(points), np.concatenate(areas))

    @cached_property
    def kernel_points(self) -> np.ndarray:
        """(N, 3) float64 for the kernels: u, v, and 1.0 where the detection may be merged
        markers (its area at least ``MERGED_AREA_RATIO`` times the median, or unknown)."""
        out = np.ones((len(self.points), 3))
        out[:, :2] = self.points
        if self.areas is not None and len(self.areas):
            ranked = np.sort(self.areas)  # the median; np.median costs 20 us on a dozen areas
            median = 0.5 * (ranked[(len(ranked) - 1) // 2] + ranked[len(ranked) // 2])
            out[:, 2] = self.areas >= MERGED_AREA_RATIO * median
        return out

    @property
    def n_views(self) -> int:
        return len(self.start) - 1

    @property
    def counts(self) -> np.ndarray:
        """(V,) int64: number of detections in each view."""
        return np.diff(self.start)

    @property
    def views_seen(self) -> int:
        """How many views have at least one detection (each compares every marker)."""
        return int(np.count_nonzero(self.counts))

    def view(self, v: int) -> np.ndarray:
        return self.points[self.start[v] : self.start[v + 1]]

    def views(self, indices: Sequence[int]) -> Detections:
        """The detections of these views only, in this order, areas included."""
        areas = None if self.areas is None else [
            self.areas[self.start[v] : self.start[v + 1]] for v in indices]
        return Detections.from_views([self.view(v) for v in indices], areas)


def _group_starts(groups: Sequence[np.ndarray]) -> np.ndarray:
    """(G + 1,) int64 offsets of consecutive groups in their concatenation: ``Detections.start``."""
    start = np.zeros(len(groups) + 1, dtype=np.int64)
    start[1:] = np.cumsum([len(g) for g in groups])
    return start


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
    """Eq. 5 for one posture, in pixels (read as blobs when ``fusion_px`` > 0).

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
            q, model.arrays, rig.arrays,
            _kernels.Image.of(detections.kernel_points, detections.start, view_offsets(offsets, rig),
                              penalty=empty_view_penalty_px, fuse_px=check_fusion(fusion_px)),
        )
    )


def outside_error(dofs: np.ndarray, detections: Detections, *, model: KinematicModel, rig: Rig,
                  offsets: np.ndarray | None = None, fusion_px: float = 0.0,
                  empty_view_penalty_px: float = DEFAULT_EMPTY_VIEW_PENALTY_PX) -> tuple[int, float]:
    """The marker projections of posture ``dofs`` (D,) beyond their view's region
    (``Rig.regions``) by more than half a marker's diameter (``fusion_px`` /
    :data:`FUSION_DIAMETERS`), in views with detections: the objective charges them
    ``empty_view_penalty_px`` each. How many, and the pixels of Eq. 5 they add (each one's
    distance to its nearest detection). No attempt can lower that share: no detection can
    lie where the camera does not look. ``offsets`` (V, 2) as :func:`view_error`."""
    q = model._check_postures(dofs)[0]
    check_views(detections, rig)
    image = _kernels.Image.of(detections.kernel_points, detections.start, view_offsets(offsets, rig),
                              penalty=empty_view_penalty_px, fuse_px=check_fusion(fusion_px))
    count, px = _kernels.outside_error(q, model.arrays, rig.arrays, image)
    return int(count), float(px)


def marker_errors(markers: np.ndarray, detections: Detections) -> np.ndarray:
    """Each projected marker's distance to the nearest detection of its view (its Eq. 5 term).

    Parameters
    ----------
    markers : (V, M, 2) float64, full-frame pixels.
    detections : one group per view.

    Returns
    -------
    (V, M) float64 pixels; NaN in a view without detections (Eq. 5 charges it a constant).

    >>> det = Detections.from_views([[[0.0, 0.0], [10.0, 0.0]], []])
    >>> marker_errors(np.array([[[3.0, 4.0]], [[1.0, 1.0]]]), det).tolist()
    [[5.0], [nan]]
    """
    out = np.full(markers.shape[:2], np.nan)
    for v in range(markers.shape[0]):
        points = detections.view(v)
        if len(points):
            out[v] = np.sqrt(nearest_detection(markers[v], points)[1])
    return out


def nearest_detection(proj: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of the projections ``proj`` (k, 2) of one view, its nearest detection of that
    view (``points`` (n, >= 2), n > 0, u and v first): (index (k,), squared distance (k,) px²).

    >>> nearest_detection(np.array([[3.0, 4.0], [9.0, 0.0]]), np.array([[0.0, 0.0], [10.0, 0.0]]))
    (array([0, 1]), array([25.,  1.]))
    """
    du = proj[:, :1] - points[:, 0]
    dv = proj[:, 1:2] - points[:, 1]
    d2 = du * du + dv * dv  # (k, n)
    nearest = d2.argmin(axis=1)
    return nearest, d2[np.arange(len(proj)), nearest]


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
