"""Overlays: projected markers land on their pixels, in the colour of the image's mark."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.error import Detections, fusion_distance, marker_errors, view_error
from core.fit import Status
from core.model import KinematicModel
from core.overlay import (
    DETECTION_BGR,
    DETECTION_RADIUS_PX,
    MARK_BGR,
    TILE_WIDTH_PX,
    _sheet,
    _tile,
    draw,
    header,
    image_marks,
    job_from_report,
    select_images,
)
from core.results import AnglesTable
from core.rig import Rig

# A root at (60.5, 80.5) turning about z, a tip 40 units along its x axis: with the identity
# projection the root marker images at pixel (col 60, row 80); the tip at (col 100, row 80)
# for a = 0 and at (col 60, row 120) for a = 90 degrees.
STICK = KinematicModel.from_xml(
    '<model name="stick" units="px">'
    '<joint name="root"><offset x="60.5" y="80.5" z="0"/><dof axis="z" name="a" min="-100" max="100"/>'
    '</joint><joint name="tip" parent="root"><offset x="40" y="0" z="0"/></joint>'
    '<marker name="M0" joint="root" x="0" y="0" z="0"/><marker name="M1" joint="tip" x="0" y="0" z="0"/>'
    "</model>"
)
PIXELS = Rig.from_dict({"views": [{"name": "side", "projection": {
    "type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}}]})


def table(dofs: list[float], errors: list[float], statuses: list[Status],
          alternative: list[float] | None = None) -> AnglesTable:
    n = len(dofs)
    return AnglesTable(
        dof_names=["a"], samples=np.arange(n), frames=np.arange(n), fields=[""] * n,
        times=np.arange(n) / 50.0, dofs=np.array(dofs, dtype=float).reshape(n, 1),
        errors=np.array(errors, dtype=float), attempts=np.ones(n, dtype=np.int64),
        statuses=statuses, error_per_marker=np.full(n, np.nan),
        alternative_deg=np.full(n, np.nan) if alternative is None else np.array(alternative, dtype=float),
    )


@pytest.mark.parametrize(
    ("angle", "tip_pixel"), [(0.0, (80, 100)), (90.0, (120, 60))])
@pytest.mark.parametrize(
    ("status", "alternative", "mark"),
    [(Status.OK, None, "ok"), (Status.OVER_THRESHOLD, None, "over_threshold"),
     (Status.OK, [7.5], "ambiguous")])
def test_projected_markers_land_on_their_pixels_in_the_mark_colour(
        angle, tip_pixel, status, alternative, mark):
    frame = np.zeros((200, 200), dtype=np.uint8)
    detections = Detections.from_views([[[150.5, 150.5]]])
    marks = image_marks(table([angle], [1.0], [status], alternative), 0, detections,
                        model=STICK, rig=PIXELS)
    assert marks.mark == mark
    (image,) = draw([frame], marks, model=STICK, rig=PIXELS)
    colour = list(MARK_BGR[mark])
    assert image[80, 60].tolist() == colour  # the root marker
    assert image[tip_pixel].tolist() == colour
    assert image[150, 150 + DETECTION_RADIUS_PX].tolist() == list(DETECTION_BGR)  # the ring
    assert image[150, 150].tolist() == [0, 0, 0]  # ... around the detection, left visible
    assert image[190, 190].tolist() == [0, 0, 0]  # nothing drawn far from the marks
    assert frame.max() == 0  # the input is not drawn on


def test_an_image_without_detections_draws_no_model():
    marks = image_marks(table([np.nan], [np.nan], [Status.NO_DETECTIONS]), 0,
                        Detections.from_views([[]]), model=STICK, rig=PIXELS)
    (image,) = draw([np.zeros((200, 200, 3), dtype=np.uint8)], marks, model=STICK, rig=PIXELS)
    assert np.all(np.isnan(marks.markers)) and image[80, 60].tolist() == [0, 0, 0]


def test_the_header_gives_the_error_per_marker_the_threshold_is_compared_with():
    """A whole animal's Eq. 5 error is tens of pixels where every marker is within a pixel:
    the header also gives it per compared marker projection, where angles.csv has it."""
    rows = table([0.0, 0.0], [39.93, 2.0], [Status.OK, Status.OK])
    rows.error_per_marker[0] = 0.106
    det = Detections.from_views([[[60.5, 80.5], [100.5, 80.5]]])
    first, second = (header(image_marks(rows, k, det, model=STICK, rig=PIXELS)) for k in (0, 1))
    assert first == "frame 0  sample 0  error 39.93 px (0.11 per marker)  ok"
    assert second == "frame 1  sample 1  error 2.00 px  ok"


@pytest.mark.parametrize(("videos", "columns"), [(1, 4), (2, 2), (4, 1), (6, 1)])
def test_contact_sheet_tiles_are_wider_and_fewer_a_row_with_more_cameras(videos, columns):
    """Each camera's frame keeps TILE_WIDTH_PX in a tile: four 640-px frames side by side
    make a 1280-px tile, one to a row (a 320-px tile showed each camera 80 px wide)."""
    side = np.full((480, videos * 640, 3), 90, np.uint8)
    tile = _tile(side, "frame 0", MARK_BGR["ok"], videos)
    assert tile.shape[1] == videos * TILE_WIDTH_PX
    sheet = _sheet([tile] * 5, videos)
    assert sheet.shape[1] == columns * tile.shape[1]


def test_marker_errors_are_the_terms_of_eq5():
    detections = Detections.from_views([[[60.5, 83.5], [100.5, 80.5], [5.0, 5.0]]])
    marks = image_marks(table([0.0], [3.0], [Status.OK]), 0, detections, model=STICK, rig=PIXELS)
    np.testing.assert_allclose(marks.errors, [[3.0, 0.0]])
    assert marks.errors.sum() == pytest.approx(
        view_error(np.array([0.0]), detections, model=STICK, rig=PIXELS))
    assert np.isnan(marker_errors(marks.markers, Detections.from_views([[]]))).all()


def test_root_tracking_offsets_move_the_marks():
    offsets = np.array([[10.0, -20.0]])
    marks = image_marks(table([0.0], [1.0], [Status.OK]), 0, Detections.from_views([[]]),
                        model=STICK, rig=PIXELS, offsets=offsets)
    np.testing.assert_allclose(marks.markers[0], [[70.5, 60.5], [110.5, 60.5]])


def test_selection_is_the_worst_errors_then_every_ambiguous_image():
    t = table([0.0] * 5, [1.0, 9.0, np.nan, 4.0, 2.0], [Status.OK] * 5,
              [np.nan, np.nan, np.nan, np.nan, 3.0])
    assert select_images(t, 2) == [1, 3, 4]
    assert select_images(t, 0) == [4]
    assert select_images(t, 10) == [1, 3, 4, 0]


def test_an_overlay_from_a_report_reads_the_blobs_the_fit_read():
    """``mocap overlay`` on a finished fit: its source restores the blobs a view's edge cuts
    with the marker diameter the fit used (its fusion distance's), so the detections drawn
    are the points the fit compared with; a fit without fusion restores none."""
    settings = {"detector": {}, "field_order": None, "root_tracking": None,
                "fit": {"fusion_px": fusion_distance(5.0)}}
    report = {"deinterlaced": False, "settings": settings}
    job = job_from_report(report, [Path("clip.avi")], model=STICK, rig=PIXELS)
    assert job.source.marker_px == pytest.approx(5.0)
    report["settings"]["fit"] = {"fusion_px": 0.0}
    assert job_from_report(report, [Path("clip.avi")], model=STICK, rig=PIXELS).source.marker_px == 0.0
    report["settings"]["fit"] = None
    with pytest.raises(ValueError, match=r"report\.json lacks"):
        job_from_report(report, [Path("clip.avi")], model=STICK, rig=PIXELS)
