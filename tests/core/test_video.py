"""Video input: probing, seeking into a range, several videos per rig, broken files."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from core import video as video_module
from core.movement import natural_movements
from core.render import render_frames
from core.video import MAX_FRAME_MISMATCH, VideoError, VideoSet, probe, write_video

DATA = Path(__file__).parents[1] / "data"
WIDTH, HEIGHT = 720, 576


def index_frame(i: int) -> np.ndarray:
    """Frame ``i``: a bright column at u = 16 i and a bright row at v = 8 + 4 i (as the H.264 fixture)."""
    image = np.full((HEIGHT, WIDTH), 16, dtype=np.uint8)
    image[:, 16 * i : 16 * i + 8] = 235
    image[8 + 4 * i : 12 + 4 * i, :] = 235
    return image


def frame_index(frame: np.ndarray) -> int:
    """Read the index back from a decoded frame (lossy codecs blur the edges, not the bar)."""
    return int(np.argmax(frame[300, :, 0] > 128)) // 16


def write(path: Path, fourcc: str, n: int, fps: float = 25.0) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (WIDTH, HEIGHT), False)
    assert writer.isOpened(), fourcc
    for i in range(n):
        writer.write(index_frame(i))
    writer.release()
    return path


@pytest.fixture(params=[("FFV1", ".avi"), ("MJPG", ".avi"), ("mp4v", ".mp4"), ("XVID", ".avi"),
                        ("dvsd", ".avi"), ("h264", ".mp4")])
def video(request, tmp_path) -> Path:
    fourcc, suffix = request.param
    if fourcc == "h264":  # OpenCV cannot encode H.264: a committed fixture (see its script)
        return shutil.copy(DATA / "frames_h264.mp4", tmp_path / "h264.mp4")
    return write(tmp_path / f"{fourcc}{suffix}", fourcc, 40)


def test_probe_reports_frames_rate_and_size(video):
    info = probe(video)
    assert (info.frames, info.fps, info.width, info.height) == (40, 25.0, WIDTH, HEIGHT)


def test_a_range_read_by_seeking_is_the_same_as_decoding_from_the_start(video):
    videos = VideoSet([video])
    sequential = [frames[0] for frames in videos.read(0, 40)]
    assert [frame_index(f) for f in sequential] == list(range(40))
    for first, last in [(17, 25), (1, 2), (36, 40), (12, 13)]:
        seeked = [frames[0] for frames in videos.read(first, last)]
        assert len(seeked) == last - first
        for got, want in zip(seeked, sequential[first:last], strict=True):
            np.testing.assert_array_equal(got, want)


def test_every_frame_is_a_bgr_uint8_array(tmp_path):
    (frames,) = next(VideoSet([write(tmp_path / "v.avi", "FFV1", 3)]).read(1, 2))
    assert frames.dtype == np.uint8 and frames.shape == (HEIGHT, WIDTH, 3)
    np.testing.assert_array_equal(frames[:, :, 0], index_frame(1))


def test_synchronised_videos_read_together(tmp_path):
    a = write(tmp_path / "a.avi", "FFV1", 30)
    b = write(tmp_path / "b.avi", "FFV1", 30 + MAX_FRAME_MISMATCH)
    videos = VideoSet([a, b])
    assert videos.frames == 30
    pairs = list(videos.read(28, 30))
    assert [(frame_index(x), frame_index(y)) for x, y in pairs] == [(28, 28), (29, 29)]


def test_videos_whose_lengths_differ_beyond_the_tolerance_are_refused(tmp_path):
    a = write(tmp_path / "a.avi", "FFV1", 30)
    b = write(tmp_path / "b.avi", "FFV1", 31 + MAX_FRAME_MISMATCH)
    with pytest.raises(VideoError, match="same number of frames"):
        VideoSet([a, b])


def test_videos_with_other_frame_rates_are_refused(tmp_path):
    a = write(tmp_path / "a.avi", "FFV1", 10, fps=25)
    b = write(tmp_path / "b.avi", "FFV1", 10, fps=30)
    with pytest.raises(VideoError, match="frame rate"):
        VideoSet([a, b])


def test_a_range_outside_the_video_is_refused(tmp_path):
    videos = VideoSet([write(tmp_path / "v.avi", "FFV1", 5)])
    with pytest.raises(ValueError, match="not within"):
        list(videos.read(3, 6))
    assert list(videos.read(5, 5)) == []


def test_a_truncated_file_reports_the_frames_it_really_holds(tmp_path):
    path = write(tmp_path / "v.avi", "MJPG", 50)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 6 // 10])  # the AVI header still announces 50
    info = probe(path)
    assert 20 <= info.frames < 50
    frames = [f[0] for f in VideoSet([path]).read(0, info.frames)]
    assert [frame_index(f) for f in frames] == list(range(info.frames))


@pytest.mark.parametrize("announced", [7, 0, 12, 30])
def test_the_real_frame_count_is_found_whatever_the_container_announces(tmp_path, announced):
    path = write(tmp_path / "v.avi", "FFV1", 12)
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    try:
        assert video_module._decodable_frames(capture, max(announced, 1)) == 12
    finally:
        capture.release()


@pytest.mark.parametrize(
    ("content", "match"),
    [(b"", "not a video"), (b"just some notes\n" * 100, "not a video"),
     (b"RIFF\x00\x00\x00\x00AVI LIST", "not a video")],
)
def test_files_that_are_not_videos_give_one_clear_error(tmp_path, content, match):
    path = tmp_path / "trial.avi"
    path.write_bytes(content)
    with pytest.raises(VideoError, match=match) as info:
        probe(path)
    assert str(path) in str(info.value)


def test_a_missing_file_and_a_directory_are_refused(tmp_path):
    with pytest.raises(VideoError, match="no such video"):
        probe(tmp_path / "missing.avi")
    with pytest.raises(VideoError, match="no such video"):
        probe(tmp_path)


def test_a_name_that_looks_like_an_image_sequence_is_read_as_one_file(tmp_path):
    path = write(tmp_path / "trial%03d.avi", "FFV1", 4)
    assert probe(path).frames == 4


def test_each_open_video_decodes_on_one_thread(video):
    """--jobs N runs N processes: FFmpeg's own threads would put more than a core under each."""
    capture = video_module._open(video)
    try:
        assert capture.get(cv2.CAP_PROP_N_THREADS) == video_module.DECODE_THREADS == 1
    finally:
        capture.release()


# ---- writing ------------------------------------------------------------------------------------


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
