"""Video files: input in any container and codec OpenCV's bundled FFmpeg decodes, read by frame
range, and lossless output for rendered clips (:func:`write_video`).

Labs bring AVI/DV, MJPG, MPEG-4, H.264 MP4, FFV1 … files, one per camera. This
module probes them (frame count, fps, size), checks that the videos of one rig
agree, and reads a frame range by seeking to its first frame, so that a chunk
in the middle of a long video costs only its own frames and memory holds one
frame per video at a time, whatever the video's length.

Containers do not always tell the truth: a truncated file or a rewritten index
may announce more frames than it holds. :func:`probe` therefore decodes the
last announced frame and, if that fails, finds the real last frame by bisection
(a few seeks, never a full decode); a range that still runs out early raises
:class:`VideoError` rather than returning short.

Every failure is one :class:`VideoError` naming the file and the problem.
Files are opened with the FFmpeg backend only, by absolute path, so neither a
``%d`` in a name (OpenCV's image-sequence reader) nor a ``proto:`` prefix
(FFmpeg's protocols) can make the reader open something else.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from core._checks import check_positive

__all__ = ["MAX_FRAME_MISMATCH", "MAX_FRAME_PIXELS", "VideoError", "VideoInfo", "VideoSet",
           "check_synchronised", "probe", "write_video"]

# Videos of one rig are cut from synchronised cameras, but their files may end a
# frame or two apart (a camera started late, a trailing partial frame dropped).
# Up to this many frames the shortest one decides; beyond it the set is refused.
MAX_FRAME_MISMATCH = 2
# Largest frame (width × height, from the container's header) that is decoded: 4096 × 4096,
# 48 MiB per BGR frame. Lab cameras are PAL to 4K (8.3 Mpx); a file announcing more is
# refused before its first frame is allocated. A module setting: a service may lower it.
MAX_FRAME_PIXELS = 4096 * 4096
# Relative difference of frame rates still considered the same rate (25 vs 25.0001).
_FPS_TOLERANCE = 1e-3
# FFmpeg decoding threads per open file. One: `mocap fit --jobs N` and the service's workers
# run one process per core, and FFmpeg's own threads would put more than a core under each
# (docs/ENGINE_NOTES.md, "Threads"). More cores: more processes.
DECODE_THREADS = 1


class VideoError(ValueError):
    """A video that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`probe` learnt of one file: decodable frames, rate and frame size (pixels).

    ``announced_frames`` is the container's own count (0 if it gives none): more than
    ``frames`` for a truncated file.
    """

    path: Path
    frames: int
    fps: float
    width: int
    height: int
    announced_frames: int = 0


def probe(path: str | Path) -> VideoInfo:
    """Open ``path``, check that it decodes, and return its real frame count, fps and size.

    Raises
    ------
    VideoError
        If the file is missing, not a video FFmpeg decodes, holds no frame, or
        has no usable frame rate.
    """
    path = _absolute(path)
    capture = _open(path)
    try:
        fps = capture.get(cv2.CAP_PROP_FPS)
        announced = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        _check_frame_size(capture, path)
        first = _read_at(capture, 0)
        if first is None:
            raise VideoError(f"{path}: holds no decodable frame")
        frames = _decodable_frames(capture, max(announced, 1))
    finally:
        capture.release()
    if not (math.isfinite(fps) and fps > 0):
        raise VideoError(f"{path}: the container gives no usable frame rate ({fps!r})")
    height, width = first.shape[:2]
    return VideoInfo(path, frames, float(fps), int(width), int(height), max(announced, 0))


class VideoSet:
    """The synchronised videos of one rig (one per camera, in the rig's ``video`` order).

    Frame ``k`` of the set is frame ``k`` of every file. Their frame counts may
    differ by :data:`MAX_FRAME_MISMATCH` frames (the shortest decides), their
    frame rates not at all.
    """

    def __init__(self, paths: Sequence[str | Path]):
        if not paths:
            raise VideoError("no video file given")
        self.infos = tuple(probe(p) for p in paths)
        check_synchronised([i.path.name for i in self.infos], [i.frames for i in self.infos],
                           [i.fps for i in self.infos])

    @property
    def paths(self) -> tuple[Path, ...]:
        return tuple(i.path for i in self.infos)

    @property
    def frames(self) -> int:
        """Frames every file has."""
        return min(i.frames for i in self.infos)

    @property
    def fps(self) -> float:
        return self.infos[0].fps

    def read(self, first: int, last: int) -> Iterator[tuple[np.ndarray, ...]]:
        """Frames ``first`` to ``last - 1``: one tuple of BGR uint8 (H, W, 3) frames per index.

        Seeks every file to ``first`` and decodes forward; one frame per file is
        held at a time. Raises :class:`VideoError` if a file ends early.
        """
        if not 0 <= first <= last <= self.frames:
            raise ValueError(f"frame range [{first}, {last}) is not within 0..{self.frames}")
        if first == last:
            return
        captures = [_open(i.path) for i in self.infos]
        try:
            for capture, info in zip(captures, self.infos, strict=True):
                _seek(capture, first, info.path)
            for index in range(first, last):
                yield tuple(_next(c, i.path, index) for c, i in zip(captures, self.infos, strict=True))
        finally:
            for capture in captures:
                capture.release()


# ---- helpers -------------------------------------------------------------------------------


def _absolute(path: str | Path) -> Path:
    p = Path(path)
    if "\x00" in str(p):
        raise VideoError("a video path contains a NUL byte")
    p = p.absolute()
    if not p.is_file():
        raise VideoError(f"{p}: no such video file")
    return p


def _open(path: Path) -> cv2.VideoCapture:
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, [cv2.CAP_PROP_N_THREADS, DECODE_THREADS])
    if not capture.isOpened():
        capture.release()
        raise VideoError(f"{path}: not a video file FFmpeg can decode (or it is damaged)")
    return capture


def _check_frame_size(capture: cv2.VideoCapture, path: Path) -> None:
    """Refuse a frame size beyond :data:`MAX_FRAME_PIXELS` before one frame is decoded."""
    width = capture.get(cv2.CAP_PROP_FRAME_WIDTH)
    height = capture.get(cv2.CAP_PROP_FRAME_HEIGHT)
    if width * height > MAX_FRAME_PIXELS:
        raise VideoError(
            f"{path}: frames of {width:.0f}×{height:.0f} pixels are larger than "
            f"{MAX_FRAME_PIXELS} pixels (MAX_FRAME_PIXELS)"
        )


def _read_at(capture: cv2.VideoCapture, index: int) -> np.ndarray | None:
    """Frame ``index`` (seek, then decode), or None if there is no such frame."""
    if index > 0 and not capture.set(cv2.CAP_PROP_POS_FRAMES, index):
        return None
    if index == 0:
        capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
    ok, frame = capture.read()
    return frame if ok and frame is not None else None


def _decodable_frames(capture: cv2.VideoCapture, announced: int) -> int:
    """The real number of frames, frame 0 being known to decode.

    ``announced`` if its last frame decodes and the next does not; fewer found by
    bisection (invariant: frame ``lo`` decodes, frame ``hi`` does not); more, or
    no count at all, by decoding forward from the last announced frame.
    """
    if _read_at(capture, announced - 1) is not None:
        if not capture.grab():
            return announced
        count = announced + 1
        while capture.grab():
            count += 1
        return count
    lo, hi = 0, announced - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _read_at(capture, mid) is not None:
            lo = mid
        else:
            hi = mid
    return lo + 1


def _seek(capture: cv2.VideoCapture, index: int, path: Path) -> None:
    if index and not capture.set(cv2.CAP_PROP_POS_FRAMES, index):
        raise VideoError(f"{path}: cannot seek to frame {index}")


def _next(capture: cv2.VideoCapture, path: Path, index: int) -> np.ndarray:
    ok, frame = capture.read()
    if not ok or frame is None:
        raise VideoError(f"{path}: ended or failed to decode at frame {index}")
    return frame


def check_synchronised(names: Sequence[str], frames: Sequence[int], fps: Sequence[float]) -> None:
    """Raise :class:`VideoError` unless the videos of one rig can be read as one set: frame
    counts within :data:`MAX_FRAME_MISMATCH` of each other, the same frame rate.

    names : how the message names each video (a file name; the service: id and upload name).
    """
    if max(frames) - min(frames) > MAX_FRAME_MISMATCH:
        listing = ", ".join(f"{name}: {count}" for name, count in zip(names, frames, strict=True))
        raise VideoError(
            f"the videos of one rig must have the same number of frames (within "
            f"{MAX_FRAME_MISMATCH}); got {listing}"
        )
    for name, rate in zip(names[1:], fps[1:], strict=True):
        if abs(rate - fps[0]) > _FPS_TOLERANCE * fps[0]:
            raise VideoError(
                f"the videos of one rig must have the same frame rate; {names[0]} "
                f"has {fps[0]:g} fps, {name} {rate:g}"
            )


# ---- writing ------------------------------------------------------------------------------------

VIDEO_SUFFIXES = (".avi", ".mkv")
VIDEO_CODECS = ("FFV1", "MJPG", "dvsd")


def write_video(
    path: str | Path, frames: Iterable[np.ndarray], *, fps: float, codec: str = "FFV1"
) -> int:
    """Write frames to a video: lossless FFV1 by default, which OpenCV reads back bit-exactly.

    Frames are streamed: memory does not grow with the length of the video.

    Parameters
    ----------
    path : str or Path
        Output file, ``.avi`` or ``.mkv``; overwritten if it exists.
    frames : iterable of ndarray of shape (H, W) or (H, W, 3), uint8
        Grey frames, or colour frames in OpenCV's BGR order; all of one shape.
        ``cv2.VideoCapture`` returns grey videos as BGR with three equal channels.
    fps : float
        Frame rate stored in the file, > 0.
    codec : {'FFV1', 'MJPG', 'dvsd'}
        FFV1 (lossless), Motion JPEG (machine-vision cameras) or DV (the paper's
        PAL camcorder format; 720×576 frames only). The lossy ones are for
        measuring what labs' footage costs, not for ground truth.

    Returns
    -------
    int
        Number of frames written.

    Raises
    ------
    ValueError
        For an unsupported suffix, no frames, or a frame of another shape or dtype.
    OSError
        When OpenCV cannot open a writer for the file (missing directory, no FFV1).
    """
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"path must end in .avi or .mkv, got {str(path)!r}")
    if codec not in VIDEO_CODECS:
        raise ValueError(f"codec must be one of {', '.join(VIDEO_CODECS)}, got {codec!r}")
    rate = check_positive("fps", fps)
    writer = None
    shape = None
    count = 0
    try:
        for frame in frames:
            frame = np.asarray(frame)
            if shape is None:
                if frame.dtype != np.uint8 or not (
                    frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)
                ):
                    raise ValueError(
                        f"frames must be uint8 arrays (H, W) or (H, W, 3), "
                        f"got {frame.dtype} {frame.shape}"
                    )
                shape = frame.shape
                writer = cv2.VideoWriter(
                    str(path), cv2.VideoWriter_fourcc(*codec), rate,
                    (shape[1], shape[0]), isColor=frame.ndim == 3,
                )
                if not writer.isOpened():
                    raise OSError(
                        f"OpenCV cannot open a {codec} video writer for {str(path)!r} "
                        f"(does the directory exist? a frame size {codec} accepts?)"
                    )
            elif frame.shape != shape or frame.dtype != np.uint8:
                raise ValueError(
                    f"frame {count} is {frame.dtype} {frame.shape}, expected uint8 {shape}"
                )
            writer.write(np.ascontiguousarray(frame))
            count += 1
    finally:
        if writer is not None:
            writer.release()
    if count == 0:
        raise ValueError("frames is empty: a video needs at least one frame")
    return count
