"""Branches competing for blobs: the detections a branch reaches and claims, and the two-sided error.

Branches (every part with a base, a branch's own trunk too) compete for blobs. Eq. 5
charges each marker its nearest blob and never charges a blob no marker explains, so a leg
that settles on its neighbour's blobs costs nothing: both legs explain the same blobs, and
the blobs of the stolen leg stay unexplained. After the first pass, any blob claimed by
markers of two branches is a conflict; each branch in a conflict is fitted again without the
blobs the other branches claim (a conflict needs a blob too small to be two markers the
detector merged), and the new posture is kept where it lowers the
*two-sided* error (:func:`two_sided_error`: every marker's distance to its nearest blob
plus, for every blob within the branches' reach, its distance to the nearest marker, both
capped at the empty-view penalty), which does charge the stolen leg's blobs. A real
fusion (two markers imaged as one blob) survives: refitting without the shared blob raises
the error, and the first posture stays; a branch that, refined where it is, explains every
other blob at twice its ε is not searched at all (:func:`core.warm_start.explained_without`).

Here: the detections within a branch's reach (:func:`reaches`, :func:`subset`), those its
markers claim (within :data:`CLAIM_PX`: :func:`claimed`, :func:`contested_projections`),
the two-sided error, and the projections next to another part's marker
(:func:`shared_projections`) or on a blob the detector flags as merged
(:func:`on_merged_blobs`). The sweeps themselves are ``core.treefit``'s; the warm starts
(``core.warm_start``) leave out the projections these read as shared or fused.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.error import Detections, nearest_detection
from core.model import KinematicModel
from core.part_objective import seen_views, world_frames
from core.rig import Rig
from core.tree import Part, Tree, reach_points

if TYPE_CHECKING:
    from core.fit import FitParams

__all__ = ["CLAIM_PX", "FUSED_PX", "claimed", "claiming_at", "claims_of", "contested_projections",
           "explained_blobs", "on_merged_blobs", "reaches", "shared_projections", "subset",
           "two_sided_error", "within_reach"]

CLAIM_PX = 3.0  # a marker within this of its nearest blob claims it
FUSED_PX = 1.0  # a blob within this of two markers' midpoint is the two of them fused


def reaches(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, parts: list[Part],
            off: np.ndarray) -> np.ndarray:
    """(len(parts), N) bool: the detections each branch of ``parts`` can reach, its base where
    ``q`` (D,) puts it (:func:`within_reach`)."""
    pos = world_frames(q, model)[1]
    return within_reach(det.points, det.start, rig, pos[[p.base for p in parts]],
                        np.array([p.reach for p in parts]), off)


def within_reach(points: np.ndarray, start: np.ndarray, rig: Rig, origins: np.ndarray, reach: np.ndarray,
                 off: np.ndarray) -> np.ndarray:
    """(B, N) bool: which of the detections ``points`` (N, 2 or more: u, v first) grouped at
    ``start`` (V + 1,) each of B branches hanging at ``origins`` (B, 3) with reaches
    ``reach`` (B,) can reach, those inside its projected reach sphere
    (``core.tree.reach_points``) in their view."""
    proj = rig.project(reach_points(origins, reach).reshape(-1, 3)) + off[:, None, :]
    proj = proj.reshape(len(rig.views), len(reach), -1, 2)  # (V, B, 27, 2), the origin first
    gap = proj[:, :, 1:] - proj[:, :, :1]
    radius = np.sqrt(np.einsum("vbsk,vbsk->vbs", gap, gap).max(axis=2))  # (V, B)
    view = np.repeat(np.arange(len(start) - 1), np.diff(start))  # (N,)
    offset = points[None, :, :2] - proj[view, :, 0].swapaxes(0, 1)  # (B, N, 2)
    return np.sqrt(np.einsum("bnk,bnk->bn", offset, offset)) <= radius[view].T


def subset(det: Detections, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kernel points (n, 3) and view starts (V + 1,) of the detections ``keep`` selects."""
    start = np.concatenate(([0], np.cumsum(keep)))[det.start]
    return np.ascontiguousarray(det.kernel_points[keep]), start


def _claiming(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, tree: Tree,
              off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(V, M) int64: the detection (index into ``det``) each projection of a branch's marker
    at posture ``q`` claims, the nearest in its view within :data:`CLAIM_PX`, else -1; and
    (M,) each marker's branch (index into ``tree.branches``, -1 for a marker in none)."""
    return claiming_at(rig.project(model.marker_positions(q)) + off[:, None, :], det, tree)


def claiming_at(proj: np.ndarray, det: Detections, tree: Tree) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_claiming` of the marker projections ``proj`` (V, M, 2), already offset."""
    owner = np.full(proj.shape[1], -1)
    for k, part in enumerate(tree.branches):
        owner[part.markers] = k
    out = np.full(proj.shape[:2], -1)
    for v in np.flatnonzero(seen_views(det.start)):
        a, b = det.start[v], det.start[v + 1]
        nearest, d2 = nearest_detection(proj[v], det.points[a:b])
        close = (d2 <= CLAIM_PX ** 2) & (owner >= 0)
        out[v, close] = a + nearest[close]
    return out, owner


def _claims(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig, tree: Tree,
            off: np.ndarray) -> np.ndarray:
    """(B, N) bool: detections claimed (nearest, within :data:`CLAIM_PX`) by each branch's
    markers in their view."""
    return claims_of(*_claiming(q, det, model, rig, tree, off), len(tree.branches), len(det.points))


def claims_of(claiming: np.ndarray, owner: np.ndarray, branches: int, detections: int) -> np.ndarray:
    """(B, N) bool from :func:`_claiming`'s (V, M) claimed detections and (M,) owners."""
    out = np.zeros((branches, detections), dtype=bool)
    view, marker = np.nonzero(claiming >= 0)
    out[owner[marker], claiming[view, marker]] = True
    return out


def claimed(q, det, model, rig, tree, off, exclude: int) -> np.ndarray:
    """(N,) bool: detections claimed by any branch but ``exclude``."""
    claims = _claims(q, det, model, rig, tree, off)
    claims[exclude] = False
    return claims.any(axis=0)


def contested_projections(q, det, model, rig, tree, off) -> np.ndarray:
    """(V, M) bool: the projections of branch markers that claim a detection another branch
    claims too, where that detection is too small to be markers the detector merged
    (``Detections.kernel_points``' flag)."""
    claiming, owner = _claiming(q, det, model, rig, tree, off)
    claims = claims_of(claiming, owner, len(tree.branches), len(det.points))
    shared = (claims.sum(axis=0) > 1) & (det.kernel_points[:, 2] == 0.0)
    return (claiming >= 0) & shared[np.maximum(claiming, 0)]


def two_sided_error(q: np.ndarray, det: Detections, model: KinematicModel, rig: Rig,
                    off: np.ndarray, blobs: np.ndarray, cap_px: float) -> float:
    """Both sides of the match between posture ``q``'s projected markers and the blobs
    (pixels): every marker projection's distance to the nearest blob of its view, plus, for
    every detection where ``blobs`` (N,) bool is set, its distance to the nearest projected
    marker of its view, each capped at ``cap_px``.

    Eq. 5 alone lets two branches explain one blob while another goes unexplained; the
    second sum charges the unexplained one. Ghost blobs cost at most ``cap_px`` each, and so
    does a marker hidden from a camera: charged its full distance to the nearest blob (tens
    of pixels), the right leg would cost more than one posed on its neighbour's blobs or on
    ghosts.
    """
    proj = rig.project(model.marker_positions(q)) + off[:, None, :]
    total = 0.0
    for v in range(det.n_views):
        pts = det.view(v)
        if len(pts) == 0:
            total += cap_px * proj.shape[1]
            continue
        d = np.linalg.norm(proj[v][:, None, :] - pts[None, :, :], axis=2)
        total += float(np.minimum(d.min(axis=1), cap_px).sum())
        mask = blobs[det.start[v]:det.start[v + 1]]
        total += float(np.minimum(d.min(axis=0)[mask], cap_px).sum())
    return total


def shared_projections(q: np.ndarray, model: KinematicModel, rig: Rig, tree: Tree,
                       params: FitParams, off: np.ndarray) -> dict[str, np.ndarray]:
    """Per part of ``tree`` (by name), (V, m) bool: where posture ``q`` (D,) projects one of
    the part's markers within the fusion distance (at least :data:`CLAIM_PX`) of a marker
    of another part, in pixels of that view."""
    proj = rig.project(model.marker_positions(q)) + off[:, None, :]
    gap = proj[:, :, None, :] - proj[:, None, :, :]
    near = np.einsum("vijk,vijk->vij", gap, gap) < max(float(params.fusion_px), CLAIM_PX) ** 2
    part_of = np.full(len(model.markers), -1)
    for k, part in enumerate(tree.parts):
        part_of[part.markers] = k
    across = (near & (part_of[:, None] != part_of[None, :])).any(axis=2)  # (V, M)
    return {part.name: across[:, part.markers] for part in tree.parts}


def explained_blobs(proj: np.ndarray, points: np.ndarray, start: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: the detections ``points`` (N, 2 or more: u, v first) grouped at ``start``
    with a marker projection ``proj`` (V, M, 2) of their view within ``radius`` px."""
    out = np.zeros(len(points), dtype=bool)
    for v in np.flatnonzero(seen_views(start)):
        a, b = start[v], start[v + 1]
        out[a:b] = nearest_detection(points[a:b, :2], proj[v])[1] <= radius * radius
    return out


def on_merged_blobs(proj: np.ndarray, points: np.ndarray, start: np.ndarray, radius: float) -> np.ndarray:
    """(V, m) bool: the projections ``proj`` (V, m, 2) whose nearest detection of their view
    (``points`` (N, 3) grouped at ``start``, ``Detections.kernel_points``) is one the
    detector may have merged from several markers (its flag) and lies within ``radius`` px."""
    out = np.zeros(proj.shape[:2], dtype=bool)
    for v in np.flatnonzero(seen_views(start)):
        a, b = start[v], start[v + 1]
        nearest, d2 = nearest_detection(proj[v], points[a:b])
        out[v] = (points[a + nearest, 2] > 0.0) & (d2 <= radius * radius)
    return out
