"""Eq. 5 (core.error): the nearest-detection error, empty views, offsets, and the blob
reading of fused markers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scenes import detections

from core.error import Detections, view_error


def test_eq5_by_hand(locust):
    """One marker per view, a known offset to the nearest of two detections, and a ghost."""
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    proj = rig.project(model.marker_positions(q))  # (2 views, 4 markers, 2)
    side = proj[0] + [3.0, 4.0]  # every marker 5 px off in the side view
    top = np.vstack([proj[1], [[5.0, 300.0]]])  # exact, plus a far ghost
    det = Detections.from_views([side, top])
    assert view_error(q, det, model=model, rig=rig) == pytest.approx(4 * 5.0)


def test_eq5_empty_view_is_a_constant_penalty(locust):
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    proj = rig.project(model.marker_positions(q))
    det = Detections.from_views([proj[0] + [0.0, 1.0], np.zeros((0, 2))])
    for penalty in (0.0, 5.0):
        e = view_error(q, det, model=model, rig=rig, empty_view_penalty_px=penalty)
        assert e == pytest.approx(4 * 1.0 + 4 * penalty)
    nothing = Detections.from_views([np.zeros((0, 2)), np.zeros((0, 2))])
    assert math.isfinite(view_error(q, nothing, model=model, rig=rig))


def test_eq5_offsets_shift_projections(locust):
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    det = detections(model, rig, q)[0]
    offsets = np.array([[0.0, 2.0], [0.0, 0.0]])
    assert view_error(q, det, model=model, rig=rig, offsets=offsets) == pytest.approx(8.0)


def test_detections_mismatched_views_rejected(locust):
    model, rig = locust
    with pytest.raises(ValueError, match="views"):
        view_error(np.full(5, 100.0), Detections.from_views([np.zeros((1, 2))]), model=model, rig=rig)


def test_fused_markers_are_predicted_at_their_common_centroid(locust):
    """Two markers 2 px apart image as one blob at their midpoint (4 px markers)."""
    model, rig = locust
    q = np.array([170.0, 0.0, 0.0, 10.0, 90.0])
    proj = rig.project(model.marker_positions(q))
    side = proj[0].copy()
    side[1] = side[0] + [2.0, 0.0]  # pretend M1 projects 2 px from M0 ...
    fused = np.vstack([0.5 * (side[0] + side[1]), side[2:]])  # ... the camera sees one blob
    from core import _kernels

    moved = side[None].copy()
    out = np.empty_like(moved)
    _kernels.fuse_projections(moved, 4.0, out)
    np.testing.assert_allclose(out[0, 0], fused[0])
    np.testing.assert_allclose(out[0, 1], fused[0])
    np.testing.assert_allclose(out[0, 2:], side[2:])


@pytest.mark.parametrize("gap_px", [3.0, 6.0])
def test_a_view_is_read_merged_or_apart_whichever_explains_it(locust, gap_px):
    """Markers 3 px apart show as one blob at their centroid, 6 px apart as two blobs: the
    blob reading scores both images 0; plain Eq. 5 charges the merged one 1.5 px a marker."""
    model, rig = locust
    side, top = rig.project(model.marker_positions(np.array([170.0, 0.0, 0.0, 10.0, 90.0])))
    top = top.copy()
    centre = top[2:].mean(axis=0)
    half = np.array([0.0, gap_px / 2])
    top[2], top[3] = centre - half, centre + half
    blobs = top if gap_px >= 5 else np.vstack([top[:2], centre])
    det = Detections.from_views([side, blobs])
    assert _eq5_at(side, top, det, fusion_px=8.0) == pytest.approx(0.0, abs=1e-9)
    assert _eq5_at(side, top, det) == pytest.approx(gap_px if gap_px < 5 else 0.0)


def test_a_view_is_read_with_its_closer_pairs_merged_and_its_farther_apart(locust):
    """In one view, markers 3 px apart show as one blob and markers 7 px apart as two (both
    within the 8 px fusion distance): neither all-apart (1.5 px a marker on the merged blob)
    nor all-merged (3.5 px a marker off the two blobs) explains the view; merging the
    closer pair alone does, and scores 0."""
    model, rig = locust
    side = rig.project(model.marker_positions(np.array([170.0, 0.0, 0.0, 10.0, 90.0])))[0]
    top = np.array([[240.0, 438.0], [243.0, 438.0], [160.0, 440.0], [160.0, 447.0]])
    blobs = np.array([[241.5, 438.0], [160.0, 440.0], [160.0, 447.0]])
    det = Detections.from_views([side, blobs])
    assert _eq5_at(side, top, det) == pytest.approx(3.0)
    assert _eq5_at(side, top, det, fusion_px=8.0) == pytest.approx(0.0, abs=1e-9)


def _eq5_at(side, top, det, fusion_px=0.0):
    """The objective of imaged markers (side, top) against ``det``, through the kernel."""
    from core import _kernels

    raw = np.ascontiguousarray(np.stack([side, top]))
    fused = np.empty_like(raw)
    if fusion_px > 0:
        _kernels.fuse_projections(raw, fusion_px, fused)
    index, dist, claims = np.empty(4, dtype=np.int64), np.empty(4), np.empty(len(det.points), dtype=np.int64)
    return _kernels.blob_error(raw, fused, det.kernel_points, det.start, 5.0, fusion_px, 0.0, np.inf,
                               index, dist, claims, _kernels.NO_UNSEEN)


def _sized(views: list[np.ndarray], large: tuple[int, int] | None = None) -> Detections:
    """Detections of these views, each a marker's area (20 px) but detection ``large``
    ((view, index)), which has the area of two merged markers."""
    areas = [np.full(len(v), 20.0) for v in views]
    if large is not None:
        areas[large[0]][large[1]] = 36.0
    return Detections.from_views(views, areas)


@pytest.mark.parametrize("merged_area", [False, True])
def test_a_blob_left_unexplained_beside_two_markers_on_one_blob_is_charged(locust, merged_area):
    """Two markers put on one blob no larger than one marker, 6 px from another that nobody
    claims: the blob reading charges the lone blob its distance (6 px); plain Eq. 5 charges
    nothing. Where the shared blob has the area of two merged markers, the two markers are
    what the detector saw, and the lone blob is a ghost: charged nothing."""
    model, rig = locust
    side = rig.project(model.marker_positions(np.array([170.0, 0.0, 0.0, 10.0, 90.0])))[0]
    top = np.array([[240.0, 438.0], [227.0, 438.0], [160.0, 440.0], [160.0, 440.5]])
    blobs = np.array([[240.0, 438.0], [227.0, 438.0], [160.0, 440.25], [160.0, 446.25]])
    det = _sized([side, blobs], (1, 2) if merged_area else None)
    assert _eq5_at(side, top, det) == pytest.approx(0.5)
    assert _eq5_at(side, top, det, fusion_px=8.0) == pytest.approx(0.0 if merged_area else 6.0, abs=0.3)


def test_a_third_marker_on_a_merged_blob_leaves_its_neighbour_charged(locust):
    """Three markers on a blob with the area of two, and a blob 6 px away that nobody
    claims: two merged markers explain that area, the third does not, and the lone blob is
    charged as a squeeze left it."""
    model, rig = locust
    side = rig.project(model.marker_positions(np.array([170.0, 0.0, 0.0, 10.0, 90.0])))[0]
    top = np.array([[240.0, 438.0], [160.0, 439.5], [160.0, 440.0], [160.0, 440.5]])
    blobs = np.array([[240.0, 438.0], [160.0, 440.0], [160.0, 446.0], [300.0, 300.0]])
    det = _sized([side, blobs], (1, 1))
    assert _eq5_at(side, top, det, fusion_px=8.0) == pytest.approx(6.0, abs=0.3)

