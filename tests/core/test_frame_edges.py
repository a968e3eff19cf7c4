"""Markers that leave a view's region (its roi or its frame): the fit charges them as unseen,
and a blob the edge cuts is moved to its marker's centre.

The scene: a root translating in the image plane with four markers in two columns 30 px
apart, seen through a roi 100 px wide. At tx 85 the right column lies beyond the roi; two
blobs of something else in the roi, (70, 50) and (70, 60), sit where the right column would
lie if the animal stood 30 px to the left.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from scenes import dots_model, pixel_rig
from tree_subjects import angle_errors, insect, movement, ring_rig

import core.video
from core.ambiguity import plain_error
from core.detect import _disc_centre_depth, detect, restored_at_edges
from core.error import Detections, fused_marker_diameter, fusion_distance, outside_error, view_error
from core.fit import FitParams, ImageFit, Status, alternative_tolerance, needs_reanalysis
from core.histogram import Histograms
from core.options import FitOptions, build_fit
from core.pipeline import VideoSource
from core.render import render_frames
from core.rig import Rig, RigError
from core.sequence import fit_sequence
from core.video import probe

MARKERS = ((0.0, 0.0), (0.0, 10.0), (30.0, 0.0), (30.0, 10.0))
TRUTH = np.array([85.0, 50.0])
BLOBS = [[(85.0, 50.0), (85.0, 60.0), (70.0, 50.0), (70.0, 60.0)]]  # two markers, two other blobs
ROI = [0, 0, 100, 96]
FUSION_PX = fusion_distance(5.0)  # 5 px markers


def _scene(roi: list[int] | None) -> tuple:
    return dots_model(*MARKERS), pixel_rig(roi), Detections.from_views(BLOBS)


def test_a_view_sees_its_roi_or_its_frame_once_the_videos_are_known():
    rig = Rig.from_dict({"views": [
        {"name": "a", "video": 0, "roi": [10, 20, 100, 50],
         "projection": {"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}},
        {"name": "b", "video": 1, "projection": {"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}},
    ]})
    assert rig.regions[0].tolist() == [10, 20, 110, 70]
    assert np.isinf(rig.regions[1]).all()
    framed = rig.framed([(200, 100), (640, 480)])
    assert framed.regions[1].tolist() == [0, 0, 640, 480]
    assert framed.to_dict() == rig.to_dict()  # the rig file does not change
    with pytest.raises(RigError, match="roi"):
        rig.framed([(100, 100), (640, 480)])


def test_the_fit_reads_the_frame_off_the_video(tmp_path):
    """What ``mocap fit`` and the workers fit with: the rig of the job, framed by its video."""
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 25.0, (64, 48), False)
    for _ in range(3):
        writer.write(np.zeros((48, 64), dtype=np.uint8))
    writer.release()
    source = VideoSource((path,), pixel_rig(None, [8, 0, 16, 48]))
    assert source.rig.frames is None
    assert source.framed_rig.regions.tolist() == [[0, 0, 64, 48], [8, 0, 24, 48]]


def test_a_marker_outside_the_roi_costs_the_penalty_in_the_objective_and_its_distance_in_error_px():
    model, rig, det = _scene(ROI)
    penalty = 5.0
    objective = view_error(TRUTH, det, model=model, rig=rig, empty_view_penalty_px=penalty)
    assert objective == pytest.approx(2 * penalty)
    unbounded = view_error(TRUTH, det, model=model, rig=pixel_rig(None), empty_view_penalty_px=penalty)
    assert unbounded == pytest.approx(60.0)  # each outside marker 30 px from a blob in the roi
    off = np.zeros((1, 2))
    assert plain_error(TRUTH, det, model, rig, off, penalty) == pytest.approx(60.0)  # FORMATS §3
    assert outside_error(TRUTH, det, model=model, rig=rig) == (2, pytest.approx(60.0))
    assert outside_error(TRUTH, det, model=model, rig=pixel_rig(None)) == (0, 0.0)


@pytest.mark.parametrize("bounded", [True, False])
def test_an_insect_whose_legs_leave_one_cameras_roi_is_fitted_without_pulling_them_back(bounded):
    """Two legs, three cameras; the first camera sees only the left of its frame (a roi up
    to the 80th percentile of the markers' u there): a quarter of its projections lie beyond
    it. Fitted with the roi, every image lies within 1° of the truth at the first attempt;
    fitted as if that camera saw everything it projects to, the markers beyond are pulled
    onto the blobs it does see, and images end tens of degrees off.

    With the roi, no image offers an alternative 3-29 px above its fit: the distances of
    the projections beyond the roi (160-210 px) are not the image's residual, and read as
    one they widened the alternatives' tolerance from 2 px to 44-56 px."""
    model, rig = insect(legs=2), ring_rig(3)
    truth = movement(model, 16)
    projected = rig.project(model.marker_positions(truth)) + np.random.default_rng(1).normal(
        0.0, 0.05, (16, 3, len(model.markers), 2))
    edge = int(np.quantile(projected[:, 0, :, 0], 0.8))
    images = [Detections.from_views([p[0][p[0][:, 0] < edge], p[1], p[2]]) for p in projected]
    if bounded:
        rig = Rig((replace(rig.views[0], roi=(0, 0, edge, 480)), *rig.views[1:]))
    result = fit_sequence(images, model=model, rig=rig, histograms=Histograms.uniform(model),
                          params=FitParams(), seed=0)
    worst = angle_errors(np.array([f.dofs for f in result.fits]), truth)[:, model.rotational].max(axis=1)
    if bounded:
        assert worst.max() < 1.0
        assert all(f.attempts == 1 for f in result.fits)  # over the threshold by the unseen alone
        assert sum(f.outside[0] for f in result.fits) > 0
        for fit, det in zip(result.fits, images, strict=True):
            seen = fit.error - fit.outside[1]
            tolerance = alternative_tolerance(FitParams(), det, model, seen, len(model.dofs))
            assert all(a.objective <= fit.objective + tolerance for a in fit.alternatives if a.minimum)
    else:
        assert worst.max() > 10.0


def test_an_image_over_the_threshold_by_markers_outside_alone_is_not_reanalysed():
    model = dots_model(*MARKERS)
    params = FitParams()
    # 4 markers x 1 view: the threshold is 5 px; 60 px of the 61 are two projections outside
    fit = ImageFit(0, TRUTH, 61.0, 11.0, 1, Status.OVER_THRESHOLD, 500, (4,), outside=(2, 60.0))
    assert not needs_reanalysis(fit, model, params, typical=0.5)  # 11 - 10 px: not an outlier
    assert needs_reanalysis(replace(fit, error=64.0), model, params)  # 4 px on two projections
    assert needs_reanalysis(replace(fit, outside=(0, 0.0)), model, params)
    assert needs_reanalysis(replace(fit, objective=12.0), model, params, typical=0.5)  # 2 px: 4x
    assert ImageFit.from_record(fit.to_record()).outside == (2, 60.0)
    legacy = {k: v for k, v in fit.to_record().items() if k != "outside"}
    assert ImageFit.from_record(legacy).outside == (0, 0.0)


def _cut_scene(tx: float) -> tuple:
    """The right column's markers ``tx + 30 - 100`` px from the roi's edge (negative:
    inside), the left column's 30 px further in; rendered with 5 px discs, detected."""
    model, rig = dots_model(*MARKERS), pixel_rig(ROI).framed([(128, 96)])
    truth = np.array([[tx, 40.0]])
    frame = next(render_frames(model, rig, truth, rng=np.random.default_rng(0), frame_size=(128, 96),
                               marker_diameter_px=5.0))
    return model, rig, truth[0], detect([frame], rig=rig)


@pytest.mark.parametrize("depth", [1.4, 0.0, -1.5])
def test_a_blob_the_edge_cuts_is_moved_to_its_markers_centre(depth):
    """A 5 px disc whose centre lies 1.4 px inside the roi's edge, on it, or 1.5 px beyond
    (a sliver shows): the part inside has its centroid 0.4-2.0 px inside the centre, and
    Eq. 5 charged the true posture that much. Restored, each centre is within 0.25 px;
    the whole discs of the left column do not move."""
    model, rig, truth, det = _cut_scene(70.0 - depth)
    restored = restored_at_edges(det, rig, 5.0)
    projected = rig.project(model.marker_positions(truth))[0]  # left column first, as found
    order = np.lexsort((det.points[:, 1], np.round(det.points[:, 0] / 10)))
    found, moved = det.points[order], restored.points[order]
    assert len(det.points) == 4
    assert np.abs(found[2:, 0] - projected[2:, 0]).min() > 0.3  # cut: biased inwards
    assert np.abs(moved - projected).max() < 0.25
    assert np.array_equal(moved[:2], found[:2])  # whole discs
    error = [view_error(truth, d, model=model, rig=rig, fusion_px=FUSION_PX) for d in (det, restored)]
    assert error[1] < 0.5 * error[0]


def test_blobs_are_left_as_detected_without_a_marker_size_an_edge_or_where_they_may_be_merged():
    _, rig, _, det = _cut_scene(70.0)
    assert restored_at_edges(det, rig, 0.0) is det
    assert restored_at_edges(det, pixel_rig(None), 5.0) is det  # a frame of unknown size
    big = np.where(det.points[:, 0] > 90, 40.0, 20.0)  # the cut blobs 4/3 of the median area
    merged = Detections(det.points, det.start, big)
    assert np.array_equal(restored_at_edges(merged, rig, 5.0).points, det.points)
    unknown = Detections(det.points, det.start, None)  # made by hand: any blob may be merged markers
    assert np.array_equal(restored_at_edges(unknown, rig, 5.0).points, det.points)


def test_a_cut_discs_centre_is_found_from_its_parts_centroid():
    t = np.linspace(-0.999, 1.0, 41)
    area = t * np.sqrt(1 - t * t) + np.arcsin(t) + 0.5 * np.pi
    seen = t + (2.0 / 3.0) * (1 - t * t) ** 1.5 / area
    assert np.abs(_disc_centre_depth(seen) - t).max() < 1e-8
    assert seen[20] == pytest.approx(4 / (3 * np.pi), abs=1e-3)  # centre on the edge: 4r / 3π


def test_the_fits_source_restores_cut_blobs_to_the_estimated_marker_size(tmp_path, monkeypatch):
    model, rig, truth, _ = _cut_scene(70.0)
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 25.0, (128, 96), False)
    for frame in render_frames(model, rig, np.tile(truth, (3, 1)), rng=np.random.default_rng(0),
                               frame_size=(128, 96), marker_diameter_px=5.0):
        writer.write(frame)
    writer.release()
    probed = []
    monkeypatch.setattr(core.video, "probe", lambda p: probed.append(p) or probe(p))
    auto = build_fit(FitOptions(), model, pixel_rig(ROI), [path]).job
    assert len(auto.source) == 3 and len(probed) == 1  # the estimate's probe serves the fit
    assert auto.source.marker_px > 0
    assert auto.source.marker_px == pytest.approx(fused_marker_diameter(auto.params.fusion_px))
    source = build_fit(FitOptions(marker_diameter_px=5.0), model, pixel_rig(ROI), [path]).job.source
    raw = replace(source, marker_px=0.0)[0]
    restored = source[0]
    assert np.abs(restored.points[:, 0] - raw.points[:, 0]).max() > 0.5
    error = [view_error(truth, d, model=model, rig=rig, fusion_px=FUSION_PX) for d in (raw, restored)]
    assert error[1] < 0.5 * error[0]
