"""De-interlacing: field rois, coordinates mapped back to the frame, field order and timing."""

from __future__ import annotations

import numpy as np
import pytest

from core.detect import detect
from core.examples import LOCUST
from core.fields import detect_fields, field_rig
from core.model import KinematicModel
from core.render import _Painter
from core.results import SampleClock
from core.rig import Rig
from core.synth import render_frames


@pytest.mark.parametrize(
    ("roi", "parity", "field_roi"),
    [((0, 0, 360, 288), 0, (0, 0, 360, 144)), ((0, 0, 360, 288), 1, (0, 0, 360, 144)),
     ((5, 288, 10, 288), 0, (5, 144, 10, 144)), ((5, 3, 10, 4), 0, (5, 2, 10, 2)),
     ((5, 3, 10, 4), 1, (5, 1, 10, 2)), ((5, 3, 10, 3), 0, (5, 2, 10, 1)),
     ((5, 3, 10, 3), 1, (5, 1, 10, 2))],
)
def test_a_field_roi_holds_exactly_the_field_rows_inside_the_frame_roi(roi, parity, field_roi):
    rig = Rig.from_dict({"views": [{"roi": list(roi), "projection": {
        "type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}}]})
    got = field_rig(rig, parity).views[0].roi
    assert got == field_roi
    _, first, _, h = got
    frame_rows = {2 * r + parity for r in range(first, first + h)}
    assert frame_rows == {y for y in range(roi[1], roi[1] + roi[3]) if y % 2 == parity}


def _interlaced_frame(seed: int):
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    rig = Rig.from_json(LOCUST / "rig.json")
    truth = np.array([[150.0, 10.0, 0.0, 20.0, 90.0], [180.0, -20.0, 5.0, 40.0, 60.0]])
    (frame,) = render_frames(model, rig, truth, rng=np.random.default_rng(seed), interlaced=True)
    return model, rig, truth, frame


def test_field_detections_are_the_markers_of_their_own_field_in_frame_pixels():
    model, rig, truth, frame = _interlaced_frame(1)
    even, odd = detect_fields([frame], rig=rig)
    proj = rig.project(model.marker_positions(truth))  # (2, V, M, 2)
    for sample, det in enumerate((even, odd)):
        for v in range(len(rig.views)):
            pts = det.view(v)
            assert len(pts) == 4
            d = np.linalg.norm(proj[sample, v][:, None] - pts[None], axis=2).min(axis=1)
            assert d.max() < 0.1, (sample, v, d)


def test_odd_first_swaps_the_order_of_the_two_images():
    _, rig, _, frame = _interlaced_frame(2)
    even, odd = detect_fields([frame], rig=rig, field_order="even-first")
    first, second = detect_fields([frame], rig=rig, field_order="odd-first")
    np.testing.assert_array_equal(first.points, odd.points)
    np.testing.assert_array_equal(second.points, even.points)


def test_a_progressive_frame_gives_the_same_markers_in_both_fields():
    model, rig, truth, _ = _interlaced_frame(3)
    (frame,) = render_frames(model, rig, truth[:1], rng=np.random.default_rng(3))
    whole = detect([frame], rig=rig)
    even, odd = detect_fields([frame], rig=rig)
    for det in (even, odd):
        assert np.abs(np.sort(det.points, axis=0) - np.sort(whole.points, axis=0)).max() < 0.3


def test_an_unknown_field_order_is_refused():
    _, rig, _, frame = _interlaced_frame(4)
    with pytest.raises(ValueError, match="field_order"):
        detect_fields([frame], rig=rig, field_order="top")
    with pytest.raises(ValueError, match="field_order"):
        SampleClock(25.0, True, "bottom")


@pytest.mark.parametrize(
    ("order", "fields"), [("even-first", ["even", "odd", "even"]), ("odd-first", ["odd", "even", "odd"])]
)
def test_the_clock_gives_field_names_frames_and_times_of_pal_fields(order, fields):
    clock = SampleClock(25.0, True, order)
    assert [clock.field(s) for s in range(3)] == fields
    assert [clock.frame(s) for s in range(3)] == [0, 0, 1]
    np.testing.assert_allclose([clock.time(s) for s in range(3)], [0.0, 0.02, 0.04])


@pytest.mark.parametrize("parity", [0, 1])
def test_field_centroids_are_unbiased_over_the_sub_pixel_position(parity):
    """A 4 px disc seen on every other row: its disc-model centre within 0.01 px at every
    sub-pixel position (the weighted centroid alone: ±0.28 px)."""
    rig = Rig.from_dict(
        {"views": [{"projection": {"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}}]})
    errors = []
    for v in np.linspace(100.0, 102.0, 40, endpoint=False):
        painter = _Painter(width=64, height=200, radius=2.0, sigma=0.0, background=20, gain=210,
                           rng=np.random.default_rng(0))
        frame = painter.paint(np.array([[30.3, v]]), np.array([[0.0, 0.0, 64.0, 200.0]]),
                              np.array([parity]))
        detections = detect_fields([frame], rig=rig)[parity]
        assert detections.counts.tolist() == [1]
        errors.append(detections.points[0] - (30.3, v))
    errors = np.array(errors)
    assert np.abs(errors[:, 0]).max() < 0.01
    assert np.abs(errors[:, 1]).max() < 0.01



@pytest.mark.parametrize("roi_y", [50, 51])
@pytest.mark.parametrize("parity", [0, 1])
def test_a_marker_in_one_field_is_found_there_whatever_the_parity_of_the_roi_top(roi_y, parity):
    """The fields are cut from the converted roi: a roi starting on an odd row must still
    give each field its own rows (frame row 2r + parity)."""
    rig = Rig.from_dict({"views": [{"roi": [10, roi_y, 50, 100], "projection": {
        "type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}}]})
    painter = _Painter(width=80, height=200, radius=2.0, sigma=0.0, background=20, gain=210,
                       rng=np.random.default_rng(0))
    centre = np.array([[30.4, 100.3]])
    frame = painter.paint(centre, np.array([[0.0, 0.0, 80.0, 200.0]]), np.array([parity]))
    fields = detect_fields([frame], rig=rig)  # even-first: (parity 0, parity 1)
    assert fields[1 - parity].counts.tolist() == [0]
    assert fields[parity].counts.tolist() == [1]
    assert np.abs(fields[parity].points[0] - centre[0]).max() < 0.01


@pytest.mark.parametrize("roi_y", [100, 101])
def test_a_one_row_roi_gives_its_row_to_one_field_and_nothing_to_the_other(roi_y):
    rig = Rig.from_dict({"views": [{"roi": [0, roi_y, 64, 1], "projection": {
        "type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}}]})
    frame = np.zeros((200, 64), dtype=np.uint8)
    frame[roi_y, 30:34] = 250
    fields = detect_fields([frame], rig=rig)
    assert fields[roi_y % 2].counts.tolist() == [1]
    assert fields[1 - roi_y % 2].counts.tolist() == [0]
    assert fields[roi_y % 2].points[0, 1] == pytest.approx(roi_y + 0.5)
