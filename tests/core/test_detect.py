"""Marker detection: filter chain, regions and sub-pixel centroids (paper Fig. 1)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scenes import dots_model

from core.detect import OPENCV_THREADS, DetectorParams, detect
from core.error import Detections
from core.rig import Rig
from core.synth import render_frames

SIZE = (128, 96)  # width, height of the test frames
# Four markers 40 and 30 px apart: isolated at any root position.
SQUARE = ((0, 0), (40, 0), (0, 30), (40, 30))


def pixel_rig(*rois: list[int] | None, videos: tuple[int, ...] | None = None) -> Rig:
    """Views with the identity projection (u, v) = (x, y), one per roi."""
    views = [
        {"name": f"v{i}", "video": videos[i] if videos else 0,
         "projection": {"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]},
         **({"roi": roi} if roi is not None else {})}
        for i, roi in enumerate(rois)
    ]
    return Rig.from_dict({"views": views})


def rendered(model, rig, postures, *, seed=0, **kwargs):
    return list(render_frames(model, rig, np.atleast_2d(postures), rng=np.random.default_rng(seed),
                              frame_size=SIZE, **kwargs))


def nearest_errors(detections: Detections, truth: np.ndarray) -> np.ndarray:
    """Distance of each true point (M, 2) to the nearest detection of view 0."""
    found = detections.view(0)
    return np.min(np.linalg.norm(truth[:, None, :] - found[None, :, :], axis=2), axis=1)


@pytest.mark.parametrize(("noise_sigma", "tolerance"), [(0.0, 0.02), (2.0, 0.1)])
def test_centroid_of_isolated_markers_is_sub_pixel_accurate(noise_sigma, tolerance):
    model, rig = dots_model(*SQUARE), pixel_rig(None)
    postures = np.random.default_rng(5).uniform([20, 20], [70, 50], (8, 2))
    frames = rendered(model, rig, postures, noise_sigma=noise_sigma)
    for posture, frame in zip(postures, frames, strict=True):
        det = detect([frame], rig=rig)
        assert det.counts.tolist() == [4]
        truth = rig.project(model.marker_positions(posture))[0]
        assert np.all(nearest_errors(det, truth) <= tolerance)


def test_roi_origin_is_added():
    model = dots_model((0, 0))
    rig = pixel_rig([0, 0, 64, 96], [64, 16, 64, 80])
    frame = rendered(model, rig, [90.3, 50.6], noise_sigma=0.0)[0]
    det = detect([frame], rig=rig)
    assert det.counts.tolist() == [0, 1]
    np.testing.assert_allclose(det.view(1)[0], [90.3, 50.6], atol=0.02)


def test_overlapping_markers_give_one_region():
    model, rig = dots_model((0, 0), (2.5, 1.0)), pixel_rig(None)
    frame = rendered(model, rig, [50.0, 40.0])[0]
    det = detect([frame], rig=rig)
    assert det.counts.tolist() == [1]
    np.testing.assert_allclose(det.view(0)[0], [51.25, 40.5], atol=0.1)  # between the two


def test_area_limits_and_erosion_drop_small_regions():
    frame = np.full(SIZE[::-1], 20, np.uint8)
    frame[10, 10] = 250  # a hot pixel
    frame[40:46, 60:66] = 250  # a 6×6 marker
    rig = pixel_rig(None)
    assert detect([frame], rig=rig, params=DetectorParams(min_area=1)).counts.tolist() == [2]
    assert detect([frame], rig=rig, params=DetectorParams(min_area=2)).counts.tolist() == [1]
    opened = DetectorParams(min_area=1, erode=1, dilate=1)
    det = detect([frame], rig=rig, params=opened)
    np.testing.assert_allclose(det.view(0), [[63.0, 43.0]])
    assert detect([frame], rig=rig, params=DetectorParams(max_area=35)).counts.tolist() == [0]


def test_otsu_and_blur_find_the_markers():
    model, rig = dots_model(*SQUARE), pixel_rig(None)
    frame = rendered(model, rig, [30.4, 25.7])[0]
    for params in (DetectorParams(threshold="otsu"), DetectorParams(blur=3, threshold=60)):
        det = detect([frame], rig=rig, params=params)
        truth = rig.project(model.marker_positions(np.array([30.4, 25.7])))[0]
        assert det.counts.tolist() == [4]
        assert np.all(nearest_errors(det, truth) <= 0.1)


@pytest.mark.parametrize(("background", "marker_level", "noise_sigma", "fixed_finds"),
                         [(150, 255, 4.0, False),  # a lit background: above a fixed threshold of 100
                          (0, 80, 0.0, False),  # markers dimmed by motion blur: under it
                          (40, 120, 8.0, True),  # a noisy grey background, dim markers
                          (20, 230, 2.0, True)])  # the renderer's default
def test_auto_threshold_finds_markers_where_a_fixed_level_does_not(background, marker_level, noise_sigma,
                                                                    fixed_finds):
    """'auto', the default, sets each view's threshold above its background level and noise
    (core.detect.auto_threshold): it finds the markers where a fixed 100 sees one region
    bigger than ``max_area`` (nothing) or no marker at all, and where 100 does."""
    model, rig = dots_model(*SQUARE), pixel_rig(None)
    frame = rendered(model, rig, [30.4, 25.7], background=background, marker_level=marker_level,
                     noise_sigma=noise_sigma, marker_diameter_px=5.0)[0]
    truth = rig.project(model.marker_positions(np.array([30.4, 25.7])))[0]
    fixed = detect([frame], rig=rig, params=DetectorParams(threshold=100.0))
    assert (fixed.counts.tolist() == [4]) == fixed_finds
    det = detect([frame], rig=rig)
    assert det.counts.tolist() == [4]
    assert np.all(nearest_errors(det, truth) <= 0.2)


def test_colour_frame_uses_the_selected_channel():
    model, rig = dots_model(*SQUARE), pixel_rig(None)
    grey = rendered(model, rig, [30.4, 25.7], noise_sigma=0.0)[0]
    bgr = np.stack([np.full_like(grey, 20), np.full_like(grey, 20), grey], axis=2)  # red markers
    truth = rig.project(model.marker_positions(np.array([30.4, 25.7])))[0]
    red = detect([bgr], rig=rig, params=DetectorParams(channel="red"))
    assert red.counts.tolist() == [4]
    assert np.all(nearest_errors(red, truth) <= 0.02)
    assert detect([bgr], rig=rig, params=DetectorParams(channel="blue")).counts.tolist() == [0]
    # Grey conversion weighs red by 0.299: 20 + 0.299·210 < 100, raise nothing at threshold 100.
    assert detect([bgr], rig=rig, params=DetectorParams(threshold=100.0)).counts.tolist() == [0]
    assert detect([bgr], rig=rig, params=DetectorParams(threshold=40)).counts.tolist() == [4]


def test_two_videos_are_detected_in_their_own_frames():
    rig = pixel_rig(None, None, videos=(0, 1))
    left = np.full((20, 30), 20, np.uint8)
    right = left.copy()
    right[5:8, 5:8] = 250
    det = detect([left, right], rig=rig)
    assert det.counts.tolist() == [0, 1]
    np.testing.assert_allclose(det.view(1)[0], [6.5, 6.5])
    with pytest.raises(ValueError, match="2 video"):
        detect([left], rig=rig)


def test_empty_and_saturated_images():
    rig = pixel_rig(None)
    assert detect([np.zeros((8, 8), np.uint8)], rig=rig).counts.tolist() == [0]
    det = detect([np.full((8, 8), 255, np.uint8)], rig=rig, params=DetectorParams(max_area=64))
    np.testing.assert_allclose(det.view(0), [[4.0, 4.0]])  # no background: plain centroid


# ---- validation -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"channel": "gray"}, "channel"),
        ({"channel": "RED"}, "channel"),
        ({"threshold": 256}, "threshold"),
        ({"threshold": -1}, "threshold"),
        ({"threshold": "bright"}, "threshold"),
        ({"threshold": True}, "threshold"),
        ({"erode": -1}, "erode"),
        ({"dilate": 1.5}, "dilate"),
        ({"blur": 4}, "blur"),
        ({"blur": -3}, "blur"),
        ({"min_area": 0}, "min_area"),
        ({"max_area": 0}, "max_area"),
        ({"min_area": 10, "max_area": 5}, "max_area"),
        ({"max_area": 2**64}, r"max_area must be an integer in 1..16777216"),  # numba's int64 overflowed
        ({"erode": 10**9}, r"erode must be an integer in 0..20"),  # 10**9 passes over every roi
        ({"blur": 10**6 + 1}, r"blur must be an integer in 0..99"),
    ],
)
def test_detector_params_validation(kwargs, name):
    with pytest.raises(ValueError, match=name):
        DetectorParams(**kwargs)


def test_wrong_number_of_frames():
    rig = pixel_rig(None)
    frame = np.zeros((8, 8), np.uint8)
    with pytest.raises(ValueError, match="one frame per video"):
        detect([frame, frame], rig=rig)


def test_a_bare_frame_is_not_a_sequence_of_frames():
    with pytest.raises(ValueError, match=r"\[frame\]"):
        detect(np.zeros((8, 8), np.uint8), rig=pixel_rig(None))


def test_roi_outside_the_frame():
    with pytest.raises(ValueError, match="outside"):
        detect([np.zeros((96, 100), np.uint8)], rig=pixel_rig([64, 0, 64, 96]))


def test_frame_must_be_uint8_grey_or_bgr():
    with pytest.raises(ValueError, match="uint8"):
        detect([np.zeros((8, 8), np.float32)], rig=pixel_rig(None))


def test_colour_channel_of_a_grey_frame():
    with pytest.raises(ValueError, match="colour"):
        detect([np.zeros((8, 8), np.uint8)], rig=pixel_rig(None),
               params=DetectorParams(channel="green"))


def test_opencv_uses_one_thread_per_process():
    """Processes are the unit of parallelism (`--jobs`, workers): OpenCV's own pool of
    threads would put more than a core under each."""
    assert cv2.getNumThreads() == OPENCV_THREADS == 1
