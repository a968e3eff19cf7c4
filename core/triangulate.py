"""Candidate 3D points from unlabelled blobs: epipolar pairing and triangulation (issue 13).

With two or more calibrated views, a blob of one view and a blob of another can be images of
one marker only if their back-projected rays (nearly) meet: the point closest to both rays,
projected back into the two views, lands on the two blobs. Every such pair gives a candidate
3D point; a candidate is then extended to every other view with a blob where it projects, the
pairs that found the same blobs are merged, and each candidate is triangulated: the point
nearest to all its rays (linear least squares), then :data:`GAUSS_NEWTON_STEPS` Gauss-Newton
steps on its reprojection error in pixels through :meth:`core.rig.Rig.project`, so affine
(mirror, orthographic), pinhole (with distortion) and DLT views are handled alike.

Ghost blobs and fused markers make spurious candidates, and a marker seen by one view makes
none. That is acceptable: candidates only propose where markers may be (starts for the
search, ``core.epipolar_start``), they never replace the search.

Every projection kind can be back-projected: an affine view's ray runs along the null
direction of its 2×3 part (the rig validates rank 2), a DLT view's from its camera centre
(rank 3 validated), and a pinhole view's from its centre through the undistorted point
(OpenCV's iterative ``undistortPoints``; where that inversion is inexact, the Gauss-Newton
steps through the forward projection correct it). Two views whose rays are parallel (two
affine views looking the same way) cannot triangulate: their pairs are skipped.

Cost is bounded: only the first :data:`MAX_BLOBS_PER_VIEW` detections of a view take part,
at most :data:`MAX_RAY_PAIRS` blob pairs are tested per image (view pairs in order until the
budget is spent), and at most :data:`MAX_CANDIDATES` pairs (the most consistent) are kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from core import _kernels
from core.error import Detections, view_offsets
from core.rig import Rig, RigArrays

__all__ = ["MAX_BLOBS_PER_VIEW", "MAX_CANDIDATES", "MAX_RAY_PAIRS", "Candidates", "ray_meetings",
           "triangulate"]

MAX_BLOBS_PER_VIEW = 128
MAX_RAY_PAIRS = 2**16  # blob pairs tested per image: 15 view pairs of 60 blobs each
MAX_CANDIDATES = 2048
PAIR_PX = 2.0  # a pair (and a further view) is consistent within this reprojection distance
GAUSS_NEWTON_STEPS = 5
_CHUNK = 256  # candidates compared at once when merging
_PARALLEL = 1e-9  # 1 - cos² of the angle between two rays below which they do not meet
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)


@dataclass(frozen=True)
class Candidates:
    """Candidate 3D marker positions of one image.

    points : ndarray of shape (K, 3), float64, model units, world frame.
    error_px : ndarray of shape (K,), float64, RMS reprojection distance over the
        supporting views, pixels.
    support : ndarray of shape (K, V), int64: for each view, the index (into
        ``Detections.points``) of the blob the candidate explains, or -1.
    """

    points: np.ndarray
    error_px: np.ndarray
    support: np.ndarray

    @property
    def n_views(self) -> np.ndarray:
        """(K,) int64: how many views support each candidate (at least 2)."""
        return np.count_nonzero(self.support >= 0, axis=1)

    def __len__(self) -> int:
        return len(self.points)

    @classmethod
    def empty(cls, n_views: int) -> Candidates:
        return cls(np.zeros((0, 3)), np.zeros(0), np.zeros((0, n_views), dtype=np.int64))


def triangulate(detections: Detections, *, rig: Rig, offsets: np.ndarray | None = None,
                tolerance_px: float = PAIR_PX, merged_px: float = 0.0) -> Candidates:
    """Pair the blobs of every two views by epipolar consistency and triangulate them.

    Parameters
    ----------
    detections : Detections, one group per rig view (full-frame pixels).
    rig : the calibrated views.
    offsets : ndarray of shape (V, 2), float64, pixels, optional; added to every
        projection of a view (root tracking, ``core.error.view_error``).
    tolerance_px : float
        A blob pair is consistent, and a further view supports a candidate, when the
        candidate projects within this many pixels of the blob.
    merged_px : float
        Added to the tolerance of a blob the detector may have merged from markers
        (``Detections.kernel_points``): two merged markers put its centre between them,
        pixels off both, and it pairs with neither one's blob in another view. 0 (the
        default) adds nothing; more slack makes more candidates, which every branch's
        triangulated start then tries (the 2-camera hexapod with glints: 33 → 26 images
        per CPU second with half a fusion distance).

    Returns
    -------
    Candidates, possibly empty: without two views that see blobs, or when no blobs pair up.
    Detections whose number of views differs from the rig's give no candidates either.
    """
    V = len(rig.views)
    if detections.n_views != V or not tolerance_px > 0:
        return Candidates.empty(V)
    off = view_offsets(offsets, rig)
    blobs, rays = _rays(detections, rig, off)
    slack = _slack(detections, merged_px)
    points, support, error = _pair(rays, blobs, detections, rig, off, tolerance_px, slack)
    if len(points) == 0:
        return Candidates.empty(V)
    support = _extend(points, support, error, detections, rig, off, tolerance_px)
    support = np.unique(support, axis=0)
    points, error = _refine(_initial(support, rays, blobs), support, detections, rig, off)
    keep = error <= tolerance_px + _support_slack(support, slack)
    points, error, support = points[keep], error[keep], support[keep]
    keep = _not_contained(support)
    return Candidates(points[keep], error[keep], support[keep])


def ray_meetings(detections: Detections, *, rig: Rig, offsets: np.ndarray | None = None,
                 tolerance_px: float = PAIR_PX) -> np.ndarray:
    """(P, 3) the points where the rays of two blobs of two views meet: the midpoints of the
    consistent pairs :func:`triangulate` starts from, neither extended to other views nor
    refined. For a few blobs whose pairs only propose where to look (a test, not a start)."""
    V = len(rig.views)
    if detections.n_views != V or not tolerance_px > 0:
        return np.zeros((0, 3))
    off = view_offsets(offsets, rig)
    blobs, rays = _rays(detections, rig, off)
    return _pair(rays, blobs, detections, rig, off, tolerance_px, _slack(detections, 0.0))[0]


def _rays(detections: Detections, rig: Rig,
          off: np.ndarray) -> tuple[list[np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
    """Per view, the indices of its first :data:`MAX_BLOBS_PER_VIEW` detections and their
    rays (:func:`_back_project`), ``off`` (V, 2) taken off the pixels first."""
    blobs = [np.arange(detections.start[v], detections.start[v + 1])[:MAX_BLOBS_PER_VIEW]
             for v in range(len(rig.views))]
    return blobs, [_back_project(rig, v, detections.points[b] - off[v]) for v, b in enumerate(blobs)]


def _back_project(rig: Rig, v: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays of ``pixels`` (n, 2) in view ``v``: origins (n, 3) and unit directions (n, 3)."""
    a = rig.arrays
    kind, P, K, dist = a.kind[v], a.P[v], a.K[v], a.dist[v]
    n = len(pixels)
    if kind == _kernels.AFFINE:
        A, b = P[:2, :3], P[:2, 3]
        direction = np.cross(A[0], A[1])
        origins = np.linalg.lstsq(A, (pixels - b).T, rcond=None)[0].T
        return origins, np.tile(direction / np.linalg.norm(direction), (n, 1))
    M, p4 = P[:, :3], P[:, 3]
    if kind == _kernels.PINHOLE:
        if n:
            normalised = cv2.undistortPointsIter(pixels.reshape(-1, 1, 2), K, dist,
                                                 None, None, _UNDISTORT_CRITERIA).reshape(-1, 2)
        else:
            normalised = np.zeros((0, 2))
        homogeneous = np.column_stack([normalised, np.ones(n)])
    else:
        homogeneous = np.column_stack([pixels, np.ones(n)])
    centre = -np.linalg.solve(M, p4)
    direction = np.linalg.solve(M, homogeneous.T).T
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.tile(centre, (n, 1)), direction


def _pair(rays: list[tuple[np.ndarray, np.ndarray]], blobs: list[np.ndarray], det: Detections,
          rig: Rig, off: np.ndarray, tolerance_px: float,
          slack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The consistent blob pairs of every two views (within :data:`MAX_RAY_PAIRS` tested):
    midpoints (P, 3) of their rays, support (P, V) (the two blobs, -1 elsewhere) and error
    (P,), the larger distance in pixels of the midpoint's projections to the two blobs, at
    most ``tolerance_px`` plus the larger ``slack`` (N,) of the two. Parallel rays are left
    out."""
    V = len(blobs)
    points, support, error, budget = [], [], [], MAX_RAY_PAIRS
    for a in range(V):
        for b in range(a + 1, V):
            na, nb = len(blobs[a]), len(blobs[b])
            if na * nb == 0 or na * nb > budget:
                continue
            budget -= na * nb
            ia, ib = np.repeat(np.arange(na), nb), np.tile(np.arange(nb), na)
            mid, ok = _closest(rays[a][0][ia], rays[a][1][ia], rays[b][0][ib], rays[b][1][ib])
            both = [a, b]
            pair = RigArrays(*(x[both] for x in rig.arrays))
            proj = _kernels.project_many(mid[None], pair)[0] + off[both, None]
            far = np.maximum(np.linalg.norm(proj[0] - det.points[blobs[a][ia]], axis=1),
                             np.linalg.norm(proj[1] - det.points[blobs[b][ib]], axis=1))
            ok &= far <= tolerance_px + np.maximum(slack[blobs[a][ia]], slack[blobs[b][ib]])
            s = np.full((int(ok.sum()), V), -1, dtype=np.int64)
            s[:, a], s[:, b] = blobs[a][ia[ok]], blobs[b][ib[ok]]
            points.append(mid[ok])
            support.append(s)
            error.append(far[ok])
    if not points:
        return np.zeros((0, 3)), np.zeros((0, V), dtype=np.int64), np.zeros(0)
    return np.concatenate(points), np.concatenate(support), np.concatenate(error)


def _slack(det: Detections, merged_px: float) -> np.ndarray:
    """(N,) pixels added to the pairing tolerance of each blob: ``merged_px`` where the
    detector may have merged markers into it (``Detections.kernel_points``), else 0."""
    return merged_px * det.kernel_points[:, 2] if merged_px > 0 else np.zeros(len(det.points))


def _support_slack(support: np.ndarray, slack: np.ndarray) -> np.ndarray:
    """(K,) the largest ``slack`` (N,) of each candidate's supporting blobs (-1: none)."""
    return np.where(support >= 0, slack[np.maximum(support, 0)], 0.0).max(axis=1, initial=0.0)


def _closest(o1: np.ndarray, d1: np.ndarray, o2: np.ndarray,
             d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Midpoints (n, 3) of the shortest segments between lines (o1 + s·d1) and (o2 + t·d2),
    unit directions, and (n,) bool: the lines are not parallel."""
    w = o1 - o2
    b = np.einsum("ij,ij->i", d1, d2)
    d, e = np.einsum("ij,ij->i", d1, w), np.einsum("ij,ij->i", d2, w)
    denominator = 1.0 - b * b
    ok = denominator > _PARALLEL
    denominator = np.where(ok, denominator, 1.0)
    s, t = (b * e - d) / denominator, (e - b * d) / denominator
    return 0.5 * (o1 + s[:, None] * d1 + o2 + t[:, None] * d2), ok


def _initial(support: np.ndarray, rays: list[tuple[np.ndarray, np.ndarray]],
             blobs: list[np.ndarray]) -> np.ndarray:
    """(K, 3) linear triangulation of each candidate: the point nearest (least squares) to the
    rays of all its supporting blobs."""
    A = np.zeros((len(support), 3, 3))
    rhs = np.zeros((len(support), 3))
    for v, (origins, directions) in enumerate(rays):
        rows = np.flatnonzero(support[:, v] >= 0)
        local = np.searchsorted(blobs[v], support[rows, v])
        o, d = origins[local], directions[local]
        projector = np.eye(3) - d[:, :, None] * d[:, None, :]  # onto the plane normal to the ray
        A[rows] += projector
        rhs[rows] += np.einsum("nij,nj->ni", projector, o)
    return np.linalg.solve(A, rhs[:, :, None])[:, :, 0]


def _residuals(points: np.ndarray, support: np.ndarray, det: Detections, rig: Rig,
               off: np.ndarray) -> np.ndarray:
    """(K, V, 2) pixels: projection of each point minus its supporting blob, 0 elsewhere."""
    proj = np.swapaxes(rig.project(points), 0, 1) + off[None]
    seen = support >= 0
    res = proj - det.points[np.where(seen, support, 0)]
    return np.where(seen[:, :, None], res, 0.0)


def _refine(points: np.ndarray, support: np.ndarray, det: Detections, rig: Rig,
            off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on the reprojection error (pixels) of every candidate over its views;
    returns the points (K, 3) and their RMS reprojection error (K,), pixels.

    A step that does not lower a candidate's error is not taken. The Jacobian is by forward
    differences through ``Rig.project``: every projection kind alike."""
    x = points.copy()
    n_seen = np.maximum(np.count_nonzero(support >= 0, axis=1), 1)
    res = _residuals(x, support, det, rig, off)
    cost = np.einsum("kvc,kvc->k", res, res)
    for _ in range(GAUSS_NEWTON_STEPS):
        h = 1e-7 * np.maximum(1.0, np.abs(x).max(axis=1))
        jac = np.stack([(_residuals(x + h[:, None] * e, support, det, rig, off) - res) / h[:, None, None]
                        for e in np.eye(3)], axis=-1)  # (K, V, 2, 3)
        JtJ = np.einsum("kvci,kvcj->kij", jac, jac) + 1e-12 * np.eye(3)
        Jtr = np.einsum("kvci,kvc->ki", jac, res)
        step = np.linalg.solve(JtJ, -Jtr[:, :, None])[:, :, 0]
        trial = x + step
        res_t = _residuals(trial, support, det, rig, off)
        cost_t = np.einsum("kvc,kvc->k", res_t, res_t)
        better = cost_t < cost
        x[better], res[better], cost[better] = trial[better], res_t[better], cost_t[better]
        if not better.any():
            break
    return x, np.sqrt(cost / n_seen)


def _extend(points: np.ndarray, support: np.ndarray, error: np.ndarray, det: Detections, rig: Rig,
            off: np.ndarray, tolerance_px: float) -> np.ndarray:
    """Support (K, V) of the :data:`MAX_CANDIDATES` consistent pairs of least ``error`` (K,)
    with, in every other view, the nearest blob within ``tolerance_px`` of the midpoint's
    projection."""
    order = np.argsort(error, kind="stable")[:MAX_CANDIDATES]
    points, support = points[order], support[order].copy()
    proj = np.swapaxes(rig.project(points), 0, 1) + off[None]
    for v in range(det.n_views):
        a, b = det.start[v], min(det.start[v + 1], det.start[v] + MAX_BLOBS_PER_VIEW)
        if a == b:
            continue
        d = np.linalg.norm(proj[:, v, None, :] - det.points[None, a:b], axis=2)
        nearest = d.argmin(axis=1)
        free = (support[:, v] < 0) & (d[np.arange(len(d)), nearest] <= tolerance_px)
        support[free, v] = a + nearest[free]
    return support


def _not_contained(support: np.ndarray) -> np.ndarray:
    """(K,) bool: candidates whose supporting blobs are not all among another candidate's
    (a pair that a candidate of more views already explains is merged into it). Compared
    :data:`_CHUNK` candidates at a time against all: memory ``_CHUNK × K × V``."""
    n = np.count_nonzero(support >= 0, axis=1)
    keep = np.ones(len(support), dtype=bool)
    for lo in range(0, len(support), _CHUNK):
        rows = support[lo:lo + _CHUNK]
        agree = ((rows[:, None] == support[None]) | (rows[:, None] < 0)).all(axis=2)
        keep[lo:lo + _CHUNK] = ~(agree & (n[None] > n[lo:lo + _CHUNK, None])).any(axis=1)
    return keep
