"""Detection preview: core.detect's own counts, its mask and centroids drawn where they are."""

from __future__ import annotations

import numpy as np
import pytest

from core.detect import DetectorParams, detect
from core.examples import LOCUST
from core.model import KinematicModel
from core.preview import CENTROID_BGR, ROI_BGR, preview_frame
from core.rig import Rig
from core.synth import render_frames


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    """Three frames of the locust example (two views in one video), two ghosts per view."""
    model, rig = KinematicModel.from_xml(LOCUST / "model.xml"), Rig.from_json(LOCUST / "rig.json")
    postures = (model.lower + model.upper) / 2 + np.array([[0.0] * 5, [10.0] * 5, [-15.0] * 5])
    return list(render_frames(model, rig, postures, rng=np.random.default_rng(1), ghosts_per_view=2))


@pytest.mark.parametrize("params", [DetectorParams(), DetectorParams(threshold="otsu", blur=3),
                                    DetectorParams(threshold=60, erode=1, dilate=1, min_area=6),
                                    DetectorParams(max_area=3)])
def test_counts_and_centroids_are_core_detects(frames, params):
    rig = Rig.from_json(LOCUST / "rig.json")
    for frame in frames:
        drawn, found, _ = preview_frame([frame], rig=rig, params=params)
        expected = detect([frame], rig=rig, params=params)
        assert found.counts.tolist() == expected.counts.tolist()
        np.testing.assert_array_equal(found.points, expected.points)
        assert len(drawn) == 1 and drawn[0].shape == (*frame.shape[:2], 3)


def test_roi_mask_and_centroids_are_drawn_at_their_pixels(frames):
    rig = Rig.from_json(LOCUST / "rig.json")
    (drawn,), found, _ = preview_frame([frames[0]], rig=rig)
    assert found.counts.min() >= 4
    for u, v in found.points:
        assert drawn[int(v), int(u)].tolist() == list(CENTROID_BGR)
    x, y, w, h = rig.views[1].roi
    assert drawn[y + h - 1, x + w // 2].tolist() == list(ROI_BGR)  # the roi's bottom edge
    # A marker pixel off the cross is tinted red: its red channel stays, blue and green halve.
    u, v = found.points[0]
    tinted = drawn[int(v) + 1, int(u) + 1].astype(int)
    original = int(frames[0][int(v) + 1, int(u) + 1])  # a grey frame
    assert tinted[2] >= original and tinted[0] < original * 0.6 + 1


def test_regions_the_area_limits_refuse_are_tinted_without_centroid(frames):
    rig = Rig.from_json(LOCUST / "rig.json")
    (drawn,), found, _ = preview_frame([frames[0]], rig=rig, params=DetectorParams(min_area=1000))
    assert found.counts.tolist() == [0, 0]
    real = detect([frames[0]], rig=rig)
    u, v = real.points[0]
    assert drawn[int(v), int(u)].tolist() != list(CENTROID_BGR)
    assert drawn[int(v), int(u), 2] > drawn[int(v), int(u), 0]  # tinted red
