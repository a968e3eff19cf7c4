"""The synthetic renderer, its video and truth files, and the natural-movement generator."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from core.detect import detect
from core.model import KinematicModel
from core.render import _disc_coverage
from core.rig import Rig
from core.synth import (
    natural_movements,
    read_truth_csv,
    render_frames,
    write_truth_csv,
    write_video,
)

EXAMPLE = Path(__file__).parents[2] / "examples" / "locust_hind_leg"
SIZE = (128, 96)  # width, height of the small test frames


def dots_model(*offsets: tuple[float, float]) -> KinematicModel:
    """Markers at fixed pixel offsets from a root that translates in x and y."""
    markers = "".join(
        f'<marker name="m{i}" joint="root" x="{x}" y="{y}" z="0"/>'
        for i, (x, y) in enumerate(offsets)
    )
    return KinematicModel.from_xml(
        '<model name="dots" units="px"><joint name="root">'
        '<dof axis="tx" name="tx" min="0" max="128"/><dof axis="ty" name="ty" min="0" max="96"/>'
        f"</joint>{markers}</model>"
    )


def pixel_rig(*rois: list[int] | None) -> Rig:
    """Views with the identity projection (u, v) = (x, y), one per roi."""
    views = [
        {"name": f"v{i}", "projection": {"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]},
         **({"roi": roi} if roi is not None else {})}
        for i, roi in enumerate(rois)
    ]
    return Rig.from_dict({"views": views})


def render_one(model, rig, posture, **kwargs) -> np.ndarray:
    kwargs.setdefault("noise_sigma", 0.0)
    kwargs.setdefault("frame_size", SIZE)
    return next(render_frames(model, rig, np.atleast_2d(posture), rng=np.random.default_rng(0),
                              **kwargs))


@pytest.fixture(scope="module")
def locust() -> tuple[KinematicModel, Rig]:
    return KinematicModel.from_xml(EXAMPLE / "model.xml"), Rig.from_json(EXAMPLE / "rig.json")


# ---- rendering --------------------------------------------------------------------------------


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


# ---- files ------------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".avi", ".mkv"])
def test_write_video_reads_back_bit_exact(tmp_path, locust, suffix):
    model, rig = locust
    q = natural_movements(model, rig, 4, rng=np.random.default_rng(1), n_sequences=1)
    frames = list(render_frames(model, rig, q, rng=np.random.default_rng(2)))
    path = tmp_path / f"clip{suffix}"
    assert write_video(path, iter(frames), fps=25.0) == 4
    cap = cv2.VideoCapture(str(path))
    back = []
    while True:
        ok, image = cap.read()
        if not ok:
            break
        back.append(image)
    cap.release()
    assert len(back) == len(frames)
    for original, read in zip(frames, back, strict=True):
        np.testing.assert_array_equal(read[:, :, 0], original)
        np.testing.assert_array_equal(read[:, :, 2], original)


def test_write_video_errors(tmp_path):
    frame = np.zeros((8, 8), np.uint8)
    with pytest.raises(ValueError, match=r"\.avi or \.mkv"):
        write_video(tmp_path / "clip.mp4", [frame], fps=25.0)
    with pytest.raises(ValueError, match="empty"):
        write_video(tmp_path / "clip.avi", [], fps=25.0)
    with pytest.raises(ValueError, match="frame 1"):
        write_video(tmp_path / "clip.avi", [frame, np.zeros((8, 9), np.uint8)], fps=25.0)
    with pytest.raises(OSError, match="cannot open"):
        write_video(tmp_path / "missing" / "clip.avi", [frame], fps=25.0)


@pytest.mark.parametrize("interlaced", [False, True])
def test_truth_csv_round_trip_and_header(tmp_path, locust, interlaced):
    model, _ = locust
    q = np.array([[170.0, -0.5, 1e-7, 10.123456789012345, 90.0],
                  [120.0, 40.0, -10.0, 0.1 + 0.2, 160.0],
                  [200.0, 0.0, -0.0, 33.3, 20.0],
                  [150.5, 1.5, 2.5, 3.5, 45.0]])
    path = tmp_path / "truth.csv"
    write_truth_csv(path, model, q, fps=25.0, interlaced=interlaced)
    lines = path.read_text().splitlines()
    assert lines[0] == "sample,frame,field,time_s,phi,psi,alpha,beta,gamma"
    if interlaced:
        assert lines[1].startswith("0,0,even,0,170,-0.5,0.0000001,")
        assert lines[4].startswith("3,1,odd,0.06,")
    else:
        assert lines[1].startswith("0,0,,0,")
        assert lines[4].startswith("3,3,,0.12,")
    assert not any("e" in cell.lower() for line in lines[1:] for cell in line.split(",")[3:])
    names, back = read_truth_csv(path)
    assert names == model.dof_names
    np.testing.assert_array_equal(back, q)


def test_read_truth_csv_rejects_another_header(tmp_path):
    path = tmp_path / "other.csv"
    path.write_text("frame,phi\n0,1\n")
    with pytest.raises(ValueError, match="header"):
        read_truth_csv(path)


# ---- natural movements --------------------------------------------------------------------------


def _check_movements(model, rig, q, n_sequences, margin, frame_size=(720, 576)):
    span = model.upper - model.lower
    inset = np.where(model.rotational, np.minimum(3.0, 0.1 * span), 0.05 * span)
    assert np.all(q >= model.lower + inset - 1e-9) and np.all(q <= model.upper - inset + 1e-9)
    proj = rig.project(model.marker_positions(q))  # (T, V, M, 2)
    for v, view in enumerate(rig.views):
        x, y, w, h = view.roi or (0, 0, *frame_size)
        assert np.all(proj[:, v] >= np.array([x, y]) + margin - 1e-9)
        assert np.all(proj[:, v] <= np.array([x + w, y + h]) - margin + 1e-9)
    bounds = np.cumsum([0] + [len(a) for a in np.array_split(np.arange(len(q)), n_sequences)])
    for b in bounds[1:-1]:  # a jump between sequences
        assert np.max(np.abs(q[b] - q[b - 1]) / span) >= 0.2
    for b0, b1 in itertools.pairwise(bounds):  # a kick in every sequence
        seq = q[b0:b1]
        sweep = max(np.max(np.abs(seq[k:] - seq[:-k]) / span) for k in range(2, 5))
        assert sweep >= 0.5


def test_natural_movements_stay_in_ranges_and_rois_with_jumps_and_kicks(locust):
    model, rig = locust
    q = natural_movements(model, rig, 240, rng=np.random.default_rng(11), n_sequences=4)
    assert q.shape == (240, 5) and q.dtype == np.float64
    _check_movements(model, rig, q, 4, 8.0)
    again = natural_movements(model, rig, 240, rng=np.random.default_rng(11), n_sequences=4)
    np.testing.assert_array_equal(q, again)
    # Smooth between kicks: most steps are small.
    steps = np.abs(np.diff(q, axis=0)) / (model.upper - model.lower)
    assert np.median(steps.max(axis=1)) < 0.05


def test_natural_movements_work_for_any_model():
    model = dots_model((0, 0), (10, 5))
    rig = pixel_rig([0, 0, 128, 96])
    q = natural_movements(model, rig, 60, rng=np.random.default_rng(2), n_sequences=3, margin_px=4)
    _check_movements(model, rig, q, 3, 4.0)


def test_natural_movements_refuse_impossible_rois(locust):
    model, _ = locust
    tiny = pixel_rig([0, 0, 10, 10])
    with pytest.raises(ValueError, match="roi"):
        natural_movements(model, tiny, 20, rng=np.random.default_rng(0), n_sequences=1)
