"""The synthetic renderer (core.render): exact disc coverage, noise, drops, offsets, rois,
ghosts, interlacing, one video's views, argument checks."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import dots_model, pixel_rig

from core.detect import detect
from core.render import _disc_coverage, render_frames
from core.rig import Rig

SIZE = (128, 96)  # width, height of the small test frames


def render_one(model, rig, posture, **kwargs) -> np.ndarray:
    kwargs.setdefault("noise_sigma", 0.0)
    kwargs.setdefault("frame_size", SIZE)
    return next(render_frames(model, rig, np.atleast_2d(posture), rng=np.random.default_rng(0),
                              **kwargs))


def test_disc_coverage_is_exact():
    centres = np.array([[10.3, 20.71], [5.5, 5.5]])
    x0 = np.floor(centres[:, 0] - 2).astype(np.int64)
    y0 = np.floor(centres[:, 1] - 2).astype(np.int64)
    cover = _disc_coverage(centres, x0, y0, 2.0, 5)
    np.testing.assert_allclose(cover.sum(axis=(1, 2)), np.pi * 4.0, rtol=1e-12)
    # A disc centred on a pixel centre covers that pixel fully; the patch is symmetric.
    assert cover[1, 2, 2] == pytest.approx(1.0)
    np.testing.assert_allclose(cover[1], cover[1].T, atol=1e-12)
    np.testing.assert_allclose(cover[1], cover[1][::-1, ::-1], atol=1e-12)


def test_noise_free_marker_centroid_is_its_projection():
    rng = np.random.default_rng(7)
    model = dots_model((0, 0), (40, 0), (0, 30), (40, 30))
    rig = pixel_rig(None)
    for posture in rng.uniform([20, 20], [70, 50], (5, 2)):
        frame = render_one(model, rig, posture).astype(np.float64) - 20.0
        for truth in rig.project(model.marker_positions(posture))[0]:
            x0, y0 = int(truth[0]) - 4, int(truth[1]) - 4
            patch = frame[y0 : y0 + 9, x0 : x0 + 9]
            ys, xs = np.mgrid[y0 : y0 + 9, x0 : x0 + 9] + 0.5
            centroid = np.array([(patch * xs).sum(), (patch * ys).sum()]) / patch.sum()
            assert np.linalg.norm(centroid - truth) <= 0.02
            assert patch.sum() == pytest.approx(210 * np.pi * 4, rel=2e-3)


def test_background_noise_has_the_requested_level_and_sigma():
    model, rig = dots_model((0, 0)), pixel_rig([0, 0, 8, 8])  # marker off its roi
    frame = render_one(model, rig, [100, 80], noise_sigma=2.0, background=20, frame_size=(256, 192))
    assert frame.mean() == pytest.approx(20.0, abs=0.05)
    assert frame.std() == pytest.approx(np.sqrt(4 + 1 / 12), abs=0.05)  # σ² + rounding


def test_drop_removes_a_marker():
    model, rig = dots_model((0, 0), (40, 0)), pixel_rig(None)
    drop = np.array([[[False, True]]])
    frame = render_one(model, rig, [30, 40], drop=drop)
    assert frame[38:43, 28:33].max() > 200
    assert frame[38:43, 68:73].max() == 20
    assert len(detect([frame], rig=rig).view(0)) == 1


def test_marker_offsets_move_each_marker_in_its_own_view():
    model, rig = dots_model((0, 0), (60, 0)), pixel_rig([0, 0, 64, 96], [64, 0, 64, 96])
    offsets = np.zeros((1, 2, 2, 2))
    offsets[0, 0, 0] = (3.25, -2.5)  # marker 0 in view 0 only; marker 1 lies in view 1
    offsets[0, 1, 1] = (-1.5, 4.0)
    frame = render_one(model, rig, [20, 40], marker_offsets_px=offsets)
    det = detect([frame], rig=rig)
    np.testing.assert_allclose(det.view(0), [[23.25, 37.5]], atol=0.02)
    np.testing.assert_allclose(det.view(1), [[78.5, 44.0]], atol=0.02)


def test_marker_is_clipped_to_its_roi():
    model = dots_model((0, 0))
    frame = render_one(model, pixel_rig([0, 0, 64, 96]), [64.2, 40.0])
    assert frame[:, 64:].max() == 20  # nothing right of the roi
    assert frame[38:43, 62:64].max() > 100  # the left part of the disc is drawn
    assert render_one(model, pixel_rig([0, 0, 64, 96]), [100.0, 40.0]).max() == 20
    # Two views splitting the frame draw the two halves: together the whole disc.
    halves = render_one(model, pixel_rig([0, 0, 64, 96], [64, 0, 64, 96]), [64.2, 40.0])
    np.testing.assert_array_equal(halves, render_one(model, pixel_rig(None), [64.2, 40.0]))


def test_ghosts_add_that_many_marker_like_regions():
    model, rig = dots_model((0, 0)), pixel_rig([0, 0, 64, 96], [64, 0, 64, 96])
    frames = render_frames(model, rig, np.array([[20.0, 20.0]] * 4), rng=np.random.default_rng(3),
                           frame_size=SIZE, ghosts_per_view=2)
    for frame in frames:
        counts = detect([frame], rig=rig).counts
        assert counts.tolist() == [3, 2]  # the marker in view 0 and 2 ghosts per view
        assert frame[:, 64:].max() > 200


def test_interlaced_frame_takes_even_rows_from_sample_2k_and_odd_rows_from_2k_plus_1():
    model, rig = dots_model((0, 0)), pixel_rig(None)
    fields = np.array([[30.0, 30.0], [90.0, 60.0]])
    (frame,) = render_frames(model, rig, fields, rng=np.random.default_rng(0), frame_size=SIZE,
                             noise_sigma=0.0, interlaced=True)
    even, odd = render_one(model, rig, fields[0]), render_one(model, rig, fields[1])
    np.testing.assert_array_equal(frame[0::2], even[0::2])
    np.testing.assert_array_equal(frame[1::2], odd[1::2])
    assert even[0::2].max() > 200 and odd[1::2].max() > 200


def test_each_video_draws_its_own_views():
    model = dots_model((0, 0))
    views = [
        {"name": f"cam{k}", "video": k,
         "projection": {"type": "affine", "matrix": [[1, 0, 0, 10 * k], [0, 1, 0, 0]]}}
        for k in range(2)
    ]
    rig = Rig.from_dict({"views": views})
    frames = [render_one(model, rig, [30.0, 40.0], video=k) for k in range(2)]
    for k, frame in enumerate(frames):
        np.testing.assert_allclose(detect([frame, frame], rig=rig).view(k), [[30.0 + 10 * k, 40.0]],
                                   atol=0.02)
        assert detect([frame], rig=pixel_rig(None)).counts.tolist() == [1]


def test_render_validates_its_arguments(locust):
    model, rig = locust
    q = np.full((3, 5), 100.0)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="trajectory"):
        render_frames(model, rig, q[:, :4], rng=rng)
    with pytest.raises(ValueError, match="interlaced"):
        render_frames(model, rig, q, rng=rng, interlaced=True)
    with pytest.raises(ValueError, match="drop"):
        render_frames(model, rig, q, rng=rng, drop=np.zeros((3, 2, 3), bool))
    with pytest.raises(ValueError, match="marker_offsets_px"):
        render_frames(model, rig, q, rng=rng, marker_offsets_px=np.zeros((3, 2, 3, 2)))
    with pytest.raises(ValueError, match="marker_offsets_px"):
        render_frames(model, rig, q, rng=rng, marker_offsets_px=np.full((3, 2, 4, 2), np.nan))
    with pytest.raises(ValueError, match="video"):
        render_frames(model, rig, q, rng=rng, video=1)
    with pytest.raises(ValueError, match="outside"):
        render_frames(model, rig, q, rng=rng, frame_size=(320, 576))
