"""Synthetic videos with known postures: the renderer of paper §3.2.

A posture trajectory of a :class:`~core.model.KinematicModel` is projected by a
:class:`~core.rig.Rig` and drawn as bright, anti-aliased round markers on a dark
background with Gaussian noise, one grey frame per video file of the rig. Ghost
markers, occlusions (dropped markers) and interlacing can be added, so that the
whole chain (detection, Eq. 5, annealing) can be measured against the truth.

- :func:`render_frames` draws the frames (lazily, one at a time);
- :func:`write_video` stores them losslessly (FFV1), bit-exact when read back;
- :func:`write_truth_csv` / :func:`read_truth_csv` store the true postures
  (FORMATS §3 columns ``sample,frame,field,time_s,<dofs>``);
- :func:`natural_movements` makes a trajectory like the paper's: concatenated
  sequences of smooth movements with fast extensions (kicks).

Pixel coordinates are full-frame (FORMATS §2): u to the right, v down, origin at
the top-left corner of the top-left pixel, pixel centres at +0.5.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Iterator
from pathlib import Path

import cv2
import numpy as np

from core.model import KinematicModel
from core.results import SampleClock
from core.rig import Rig

__all__ = [
    "natural_movements",
    "read_truth_csv",
    "render_frames",
    "write_truth_csv",
    "write_video",
]

TRUTH_FIXED_COLUMNS = ("sample", "frame", "field", "time_s")
VIDEO_SUFFIXES = (".avi", ".mkv")
VIDEO_CODECS = ("FFV1", "MJPG", "dvsd")

# Background noise: a uniform 16-bit draw mapped through the inverse CDF of the
# rounded, clipped Gaussian (exact up to a CDF step of 2**-16), ~5x faster than
# drawing 414 720 normals per frame. Marker pixels get exact Gaussian noise.
_NOISE_LEVELS = 1 << 16
# Samples per projection chunk: memory stays bounded for any trajectory length.
_CHUNK = 256


# ---- rendering ------------------------------------------------------------------------------


def render_frames(
    model: KinematicModel,
    rig: Rig,
    trajectory: np.ndarray,
    *,
    rng: np.random.Generator,
    video: int = 0,
    frame_size: tuple[int, int] = (720, 576),
    marker_diameter_px: float = 4.0,
    noise_sigma: float = 2.0,
    background: float = 20,
    marker_level: float = 230,
    ghosts_per_view: int = 0,
    drop: np.ndarray | None = None,
    marker_offsets_px: np.ndarray | None = None,
    interlaced: bool = False,
) -> Iterator[np.ndarray]:
    """Render the frames of one video file of the rig, one at a time.

    Every model marker is a disc of ``marker_diameter_px`` centred on its
    projection. A pixel's value is ``background + (marker_level - background)
    · c + noise``, rounded and clipped to 0..255, where ``c`` is the exact area
    of the pixel covered by discs (analytic disc/square overlap, summed over
    discs, so overlapping markers fuse into one brighter blob) and ``noise`` is
    Gaussian with standard deviation ``noise_sigma``, independent per pixel and
    frame. Without noise the intensity-weighted centroid (pixel centres
    weighted by ``value - background``) of an isolated marker is its projection
    to within the bias inherent to pixel sampling: <= 0.011 px for a 4 px
    marker (0.03 px at 2 px, 0.006 px at 6 px), plus < 0.002 px of rounding.
    A view's markers are drawn only inside its ``roi`` (clipped), into the
    frames of its own video file.

    Parameters
    ----------
    model : KinematicModel
    rig : Rig
        Views whose ``video`` equals ``video`` are drawn; their rois must lie in the frame.
    trajectory : ndarray of shape (T, D), float64
        One posture per sample, model-file DOF order (degrees, model units).
        A sample is a frame, or a field when ``interlaced``.
    rng : numpy.random.Generator
        The only source of randomness (noise, ghost positions).
    video : int, default 0
        Index of the rig's video file to render (``View.video``).
    frame_size : (width, height), default (720, 576)
        Frame size in pixels.
    marker_diameter_px : float, default 4.0
        Disc diameter in pixels, > 0.
    noise_sigma : float, default 2.0
        Standard deviation of the background noise in grey levels, >= 0.
    background, marker_level : float, default 20, 230
        Grey level of the background and of a fully covered marker pixel, 0..255.
    ghosts_per_view : int, default 0
        Extra marker-like discs per view per sample, uniformly at random with the
        whole disc inside the view's roi (clutter: reflections, dust). Each
        analysed image (frame, or field when interlaced) gets this many per view.
    drop : ndarray of shape (T, V, M), bool, optional
        True where marker m is not drawn in rig view v at sample t (occlusion).
        V counts every view of the rig, including those of other videos.
    marker_offsets_px : ndarray of shape (T, V, M, 2), float64, optional
        Pixels (du, dv) added to marker m's projection in rig view v at sample t
        before it is drawn: skin markers sliding over the skeleton (soft tissue),
        so that the rendered blobs are not where the model's markers project.
        V counts every view of the rig, as in ``drop``.
    interlaced : bool, default False
        If True the trajectory is per field, two samples per frame: frame k has
        its even rows (0, 2, …) from sample 2k and its odd rows from sample
        2k + 1 (even field first, 1 / (2 fps) later). T must be even.

    Yields
    ------
    ndarray of shape (height, width), uint8
        One grey frame per frame of the video: T frames, or T / 2 when interlaced.
        Every frame is a new array.

    Raises
    ------
    ValueError
        Naming the parameter, when an argument is invalid (checked at the call,
        before the first frame is drawn).
    """
    q = _validate_trajectory(trajectory, model)
    width, height = _validate_frame_size(frame_size)
    n_views, n_markers = len(rig.views), len(model.markers)
    if isinstance(video, bool) or not isinstance(video, int | np.integer) or not (
        0 <= video < rig.n_videos
    ):
        raise ValueError(
            f"video must be a video index 0..{rig.n_videos - 1} of the rig, got {video!r}"
        )
    diameter = _positive("marker_diameter_px", marker_diameter_px)
    sigma = _non_negative("noise_sigma", noise_sigma)
    bg = _grey_level("background", background)
    level = _grey_level("marker_level", marker_level)
    if isinstance(ghosts_per_view, bool) or not isinstance(ghosts_per_view, int | np.integer) or (
        ghosts_per_view < 0
    ):
        raise ValueError(f"ghosts_per_view must be an integer >= 0, got {ghosts_per_view!r}")
    if drop is not None:
        drop = np.asarray(drop)
        if drop.dtype != bool or drop.shape != (len(q), n_views, n_markers):
            raise ValueError(
                f"drop must be a boolean array of shape (T, V, M) = "
                f"({len(q)}, {n_views}, {n_markers}), got {drop.dtype} {drop.shape}"
            )
    offsets = _validate_offsets(marker_offsets_px, (len(q), n_views, n_markers))
    if interlaced and len(q) % 2:
        raise ValueError(
            f"an interlaced trajectory has two samples (fields) per frame; got T={len(q)} (odd)"
        )
    views = [i for i, v in enumerate(rig.views) if v.video == video]
    clips = np.array([_roi_rect(rig, i, width, height) for i in views], dtype=np.float64)
    painter = _Painter(
        width=width, height=height, radius=diameter / 2.0, sigma=sigma, background=bg,
        gain=level - bg, rng=rng,
    )
    return _frames(
        model, rig, q, painter, views=views, clips=clips, drop=drop, offsets=offsets,
        ghosts=int(ghosts_per_view), interlaced=bool(interlaced),
    )


def _frames(
    model: KinematicModel,
    rig: Rig,
    q: np.ndarray,
    painter: _Painter,
    *,
    views: list[int],
    clips: np.ndarray,
    drop: np.ndarray | None,
    offsets: np.ndarray | None,
    ghosts: int,
    interlaced: bool,
) -> Iterator[np.ndarray]:
    per_frame = 2 if interlaced else 1
    step = _CHUNK * per_frame
    for start in range(0, len(q), step):
        chunk = q[start : start + step]
        proj = rig.project(model.marker_positions(chunk))[:, views]  # (t, Vk, M, 2)
        if offsets is not None:
            proj = proj + offsets[start : start + step][:, views]
        keep = None if drop is None else ~drop[start : start + step][:, views]
        for first in range(0, len(chunk), per_frame):
            centres, clip_index, parity = [], [], []
            for s in range(first, first + per_frame):
                for k in range(len(views)):
                    pts = proj[s, k] if keep is None else proj[s, k][keep[s, k]]
                    if ghosts:
                        pts = np.vstack([pts, painter.ghost_centres(clips[k], ghosts)])
                    centres.append(pts)
                    clip_index.append(np.full(len(pts), k))
                    parity.append(np.full(len(pts), s - first if interlaced else -1))
            yield painter.paint(
                np.concatenate(centres), clips[np.concatenate(clip_index)],
                np.concatenate(parity),
            )


class _Painter:
    """Draws discs with exact pixel coverage on a noisy background."""

    def __init__(
        self, *, width: int, height: int, radius: float, sigma: float, background: float,
        gain: float, rng: np.random.Generator,
    ) -> None:
        self.width, self.height, self.radius = width, height, radius
        self.sigma, self.background, self.gain, self.rng = sigma, background, gain, rng
        self.patch = math.ceil(2.0 * radius) + 1  # pixels a disc can touch along one axis
        self.noise_lut = _noise_lut(background, sigma) if sigma > 0 else None
        self.flat_value = int(min(255.0, math.floor(background + 0.5)))

    def ghost_centres(self, clip: np.ndarray, n: int) -> np.ndarray:
        """(n, 2) random centres with the whole disc inside ``clip`` (x0, y0, x1, y1) if it fits."""
        middle = (clip[:2] + clip[2:]) / 2  # a roi narrower than a disc: centre it there
        lo = np.minimum(clip[:2] + self.radius, middle)
        hi = np.maximum(clip[2:] - self.radius, middle)
        return lo + (hi - lo) * self.rng.random((n, 2))

    def background_frame(self) -> np.ndarray:
        if self.noise_lut is None:
            return np.full((self.height, self.width), self.flat_value, dtype=np.uint8)
        draw = self.rng.integers(0, _NOISE_LEVELS, size=(self.height, self.width), dtype=np.uint16)
        return np.take(self.noise_lut, draw)

    def paint(self, centres: np.ndarray, clips: np.ndarray, parity: np.ndarray) -> np.ndarray:
        """One frame with discs at ``centres`` (K, 2), each clipped to its rect in ``clips``.

        ``parity`` (K,): 0 or 1 draws the disc only in even or odd rows, -1 in all rows.
        """
        frame = self.background_frame()
        reach = self.radius + 1.0
        with np.errstate(invalid="ignore"):  # NaN centres (points that do not project) fail
            ok = np.all((centres > clips[:, :2] - reach) & (centres < clips[:, 2:] + reach), axis=1)
        centres, clips, parity = centres[ok], clips[ok], parity[ok]
        if len(centres) == 0:
            return frame
        P = self.patch
        x0 = np.floor(centres[:, 0] - self.radius).astype(np.int64)
        y0 = np.floor(centres[:, 1] - self.radius).astype(np.int64)
        cover = _disc_coverage(centres, x0, y0, self.radius, P)  # (K, P, P), rows = y
        xs = x0[:, None, None] + np.arange(P)[None, None, :]
        ys = y0[:, None, None] + np.arange(P)[None, :, None]
        inside = (
            (cover > 0.0)
            & (xs >= clips[:, 0, None, None]) & (xs < clips[:, 2, None, None])
            & (ys >= clips[:, 1, None, None]) & (ys < clips[:, 3, None, None])
            & ((parity[:, None, None] < 0) | (ys % 2 == parity[:, None, None]))
        )
        if not inside.any():
            return frame
        flat = (ys * self.width + xs)[inside]
        pixels, which = np.unique(flat, return_inverse=True)
        value = self.background + 0.5 + self.gain * np.bincount(which, weights=cover[inside])
        if self.sigma > 0:
            value += self.sigma * self.rng.standard_normal(len(pixels))
        frame.ravel()[pixels] = np.clip(np.floor(value), 0, 255).astype(np.uint8)
        return frame


def _disc_coverage(
    centres: np.ndarray, x0: np.ndarray, y0: np.ndarray, radius: float, P: int
) -> np.ndarray:
    """Exact area of each pixel of a P×P patch covered by a disc.

    Parameters
    ----------
    centres : ndarray of shape (K, 2), float64, disc centres (u, v) in pixels.
    x0, y0 : ndarray of shape (K,), int64, top-left pixel of each patch.

    Returns
    -------
    ndarray of shape (K, P, P), float64 in [0, 1], indexed [disc, row, column].

    Inclusion-exclusion over the pixel corners of ``G(x, y)``, the signed disc
    area in the rectangle between the centre and (x, y).
    """
    grid = np.arange(P + 1, dtype=np.float64)
    gx = (x0[:, None] + grid[None, :]) - centres[:, 0, None]  # (K, P+1) corner x - centre
    gy = (y0[:, None] + grid[None, :]) - centres[:, 1, None]
    G = _signed_quadrant_area(gx[:, None, :], gy[:, :, None], radius)  # (K, P+1, P+1) [y, x]
    cover = G[:, 1:, 1:] - G[:, 1:, :-1] - G[:, :-1, 1:] + G[:, :-1, :-1]
    return np.clip(cover, 0.0, 1.0)


def _signed_quadrant_area(x: np.ndarray, y: np.ndarray, r: float) -> np.ndarray:
    """Area of the disc |p| <= r inside the rectangle spanned by (0, 0) and (x, y), signed.

    >>> round(float(_signed_quadrant_area(np.array(1.0), np.array(1.0), 1.0)), 12)
    0.785398163397
    >>> float(_signed_quadrant_area(np.array(-0.5), np.array(0.5), 1.0))
    -0.25
    """
    a = np.minimum(np.abs(x), r)
    b = np.minimum(np.abs(y), r)
    xc = np.sqrt(np.maximum(r * r - b * b, 0.0))  # where the circle's height equals b

    def primitive(t: np.ndarray) -> np.ndarray:  # ∫_0^t sqrt(r² - s²) ds
        root = np.sqrt(np.maximum(r * r - t * t, 0.0))
        return 0.5 * (t * root + r * r * np.arcsin(np.clip(t / r, -1.0, 1.0)))

    area = np.where(a <= xc, a * b, b * xc + primitive(a) - primitive(xc))
    return np.sign(x) * np.sign(y) * area


def _noise_lut(background: float, sigma: float) -> np.ndarray:
    """uint8 lookup (2**16,): a uniform 16-bit draw -> clip(round(background + sigma·z), 0, 255)."""
    levels = np.arange(256, dtype=np.float64)
    cdf = np.array(
        [0.5 * math.erfc(-(v + 0.5 - background) / (sigma * math.sqrt(2.0))) for v in levels]
    )
    cdf[-1] = 1.0
    u = (np.arange(_NOISE_LEVELS, dtype=np.float64) + 0.5) / _NOISE_LEVELS
    return np.searchsorted(cdf, u, side="left").astype(np.uint8)


def _roi_rect(rig: Rig, index: int, width: int, height: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of a view's roi, end exclusive; the whole frame without roi."""
    view = rig.views[index]
    if view.roi is None:
        return (0, 0, width, height)
    x, y, w, h = view.roi
    if x + w > width or y + h > height:
        raise ValueError(
            f"roi {list(view.roi)} of view '{view.name}' lies outside the {width}×{height} frame"
        )
    return (x, y, x + w, y + h)


# ---- video and truth files -------------------------------------------------------------------


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
    rate = _positive("fps", fps)
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


def write_truth_csv(
    path: str | Path,
    model: KinematicModel,
    trajectory: np.ndarray,
    *,
    fps: float,
    interlaced: bool,
) -> None:
    """Write the true postures as CSV: ``sample,frame,field,time_s,<dof names>``.

    Columns mean what they mean in ``angles.csv`` (FORMATS §3): ``sample`` is the
    0-based sample (frame, or field when ``interlaced``), ``frame`` the video
    frame, ``field`` ``even``/``odd`` when interlaced and empty otherwise,
    ``time_s`` seconds from the start of the video, then one column per DOF in
    model-file order (degrees, model units). Numbers are C-locale decimals
    without exponents, written with the shortest digits that read back exactly.

    Parameters
    ----------
    path : str or Path
    model : KinematicModel
    trajectory : ndarray of shape (T, D), float64, model-file DOF order.
    fps : float
        Video frame rate, > 0 (fields are 1 / (2 fps) apart when interlaced).
    interlaced : bool
        True if samples are fields: sample 2k is frame k's even field, 2k+1 its odd field.
    """
    q = _validate_trajectory(trajectory, model)
    clock = SampleClock(fps=_positive("fps", fps), deinterlaced=bool(interlaced))
    with Path(path).open("w", newline="") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow([*TRUTH_FIXED_COLUMNS, *model.dof_names])
        for s, row in enumerate(q):
            writer.writerow(
                [s, clock.frame(s), clock.field(s), _decimal(clock.time(s)),
                 *(_decimal(v) for v in row)]
            )


def read_truth_csv(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Read a truth CSV written by :func:`write_truth_csv`.

    Returns
    -------
    names : list of str
        DOF names, in column (model-file) order.
    dofs : ndarray of shape (T, D), float64
        True DOF values, one row per sample, in sample order.

    Raises
    ------
    ValueError
        If the header is not ``sample,frame,field,time_s,<dofs>``, or a cell is not a number.
    """
    path = Path(path)
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or tuple(rows[0][:4]) != TRUTH_FIXED_COLUMNS or len(rows[0]) < 5:
        head = rows[0] if rows else []
        raise ValueError(f"{path}: header {head} is not 'sample,frame,field,time_s,<dof names>'")
    names = rows[0][4:]
    values = np.empty((len(rows) - 1, len(names)), dtype=np.float64)
    for i, row in enumerate(rows[1:]):
        if len(row) != len(names) + 4:
            raise ValueError(
                f"{path}: line {i + 2} has {len(row)} cells, expected {len(names) + 4}"
            )
        try:
            values[i] = [float(c) for c in row[4:]]
        except ValueError:
            raise ValueError(f"{path}: line {i + 2} has a DOF cell that is not a number") from None
    return names, values


def _decimal(value: float) -> str:
    """Shortest C-locale decimal that reads back to the same float, never an exponent.

    >>> _decimal(0.02), _decimal(-0.0), _decimal(1e-7), _decimal(170.0)
    ('0.02', '0', '0.0000001', '170')
    """
    return np.format_float_positional(float(value) + 0.0, trim="-")


# ---- natural movements --------------------------------------------------------------------------


def natural_movements(
    model: KinematicModel,
    rig: Rig,
    n_samples: int,
    *,
    rng: np.random.Generator,
    n_sequences: int = 10,
    fps: float = 50.0,
    margin_px: float = 8.0,
    frame_size: tuple[int, int] = (720, 576),
) -> np.ndarray:
    """A trajectory like the paper's §3.2 test video: sequences of smooth movements with kicks.

    ``n_samples`` are split into ``n_sequences`` sequences of (almost) equal
    length, ``np.array_split`` sizes, concatenated with a jump between them (the
    next sequence starts at least a quarter of some DOF's usable range away from
    where the last one ended). Within a sequence the posture moves smoothly,
    by minimum-jerk interpolation, between random key postures 0.2–0.5 s apart
    (each key a random step from the last). Each sequence contains one fast
    extension: one or two rotational DOFs (any DOFs if the model has no
    rotation) are first brought near one end of their usable range and then
    swept to the other end (at least 70 % of it) within 2–4 samples, like a
    locust kick.

    Every sample keeps each DOF at least ``min(3, 10 % of its range)`` degrees
    (5 % of the range for translations) inside its limits, and every marker
    projection inside its view's roi (or the frame) with ``margin_px`` to spare;
    key postures whose movement would leave it are drawn again.

    Parameters
    ----------
    model : KinematicModel
    rig : Rig
    n_samples : int
        T, number of samples (frames or fields), >= 1.
    rng : numpy.random.Generator
    n_sequences : int, default 10
        Number of sequences, >= 1; reduced so that each has at least 10 samples
        (a single sequence shorter than 3 samples has no kick).
    fps : float, default 50.0
        Samples per second, used for the 0.2–0.5 s key spacing.
    margin_px : float, default 8.0
        Distance in pixels every marker projection keeps from its roi's border.
    frame_size : (width, height), default (720, 576)
        Frame size, the bounds of views without roi.

    Returns
    -------
    ndarray of shape (T, D), float64
        Postures, model-file DOF order (degrees, model units).

    Raises
    ------
    ValueError
        On invalid arguments, or if no posture (or no kick) keeps the markers in the rois.
    """
    if isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer) or n_samples < 1:
        raise ValueError(f"n_samples must be an integer >= 1, got {n_samples!r}")
    if isinstance(n_sequences, bool) or not isinstance(n_sequences, int | np.integer) or (
        n_sequences < 1
    ):
        raise ValueError(f"n_sequences must be an integer >= 1, got {n_sequences!r}")
    rate = _positive("fps", fps)
    margin = _non_negative("margin_px", margin_px)
    width, height = _validate_frame_size(frame_size)
    space = _PostureSpace(model, rig, margin, width, height)
    n_seq = max(1, min(int(n_sequences), int(n_samples) // _MIN_SEQUENCE))
    sizes = [len(a) for a in np.array_split(np.arange(int(n_samples)), n_seq)]
    sequences: list[np.ndarray] = []
    for size in sizes:
        previous = sequences[-1][-1] if sequences else None
        sequences.append(_sequence(size, space, rng, rate, previous))
    return np.concatenate(sequences)


_MIN_SEQUENCE = 10  # samples
_KEY_SPACING_S = (0.2, 0.5)
_JUMP = 0.25  # fraction of a DOF's usable range the next sequence starts away
_COCKED = 0.15  # the kicking DOF starts within this fraction of one end of its usable range
_ATTEMPTS = 200


class _PostureSpace:
    """Usable DOF box and the roi test of postures."""

    def __init__(self, model: KinematicModel, rig: Rig, margin: float, width: int, height: int):
        self.model, self.rig = model, rig
        span = model.upper - model.lower
        inset = np.where(model.rotational, np.minimum(3.0, 0.1 * span), 0.05 * span)
        self.lo, self.hi = model.lower + inset, model.upper - inset
        self.span = self.hi - self.lo
        rects = np.array([_roi_rect(rig, i, width, height) for i in range(len(rig.views))], float)
        self.bounds_lo = rects[:, None, :2] + margin  # (V, 1, 2)
        self.bounds_hi = rects[:, None, 2:] - margin
        kickers = np.flatnonzero(model.rotational)
        self.kickers = kickers if len(kickers) else np.arange(len(model.dofs))

    def valid(self, q: np.ndarray) -> bool:
        """True if every posture of ``q`` (n, D) projects every marker inside the rois."""
        proj = self.rig.project(self.model.marker_positions(np.atleast_2d(q)))  # (n, V, M, 2)
        return bool(
            np.all(np.isfinite(proj))
            and np.all(proj >= self.bounds_lo)
            and np.all(proj <= self.bounds_hi)
        )

    def random_posture(self, rng: np.random.Generator) -> np.ndarray:
        return self.lo + self.span * rng.random(len(self.lo))

    def step(self, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A random key posture around ``q``: uniform within ±half the usable range, in the box."""
        lo = np.maximum(self.lo, q - 0.5 * self.span)
        hi = np.minimum(self.hi, q + 0.5 * self.span)
        return lo + (hi - lo) * rng.random(len(q))


def _min_jerk(q0: np.ndarray, q1: np.ndarray, n: int) -> np.ndarray:
    """(n + 1, D) postures from q0 to q1 in n sample intervals, minimum-jerk profile."""
    s = np.arange(n + 1, dtype=np.float64) / n
    profile = s**3 * (10.0 - 15.0 * s + 6.0 * s * s)
    return q0 + (q1 - q0) * profile[:, None]


def _sequence(
    size: int,
    space: _PostureSpace,
    rng: np.random.Generator,
    fps: float,
    previous: np.ndarray | None,
) -> np.ndarray:
    for _ in range(20):
        seq = _try_sequence(size, space, rng, fps, previous)
        if seq is not None:
            return seq
    raise ValueError(
        "could not generate a movement that keeps every marker inside its view's roi "
        "(rois too small for the model, or margin_px too large)"
    )


def _try_sequence(
    size: int,
    space: _PostureSpace,
    rng: np.random.Generator,
    fps: float,
    previous: np.ndarray | None,
) -> np.ndarray | None:
    lo_gap = max(2, round(_KEY_SPACING_S[0] * fps))
    hi_gap = max(lo_gap, round(_KEY_SPACING_S[1] * fps))
    out = np.empty((size, len(space.lo)))
    kick = min(int(rng.integers(2, 5)), size - 1) if size >= 3 else 0
    # The kick runs from sample ks to ks + kick; ks leaves room for a smooth approach.
    latest = size - 1 - kick
    ks = int(rng.integers(lo_gap, latest + 1)) if kick and latest >= lo_gap else 0
    if kick and ks == 0:  # the sequence starts cocked
        q = _cocked_and_kick(out, 0, 0, kick, None, space, rng, previous)
        if q is None:
            return None
        t = kick
    else:
        q = _start_posture(space, rng, previous)
        if q is None:
            return None
        out[0], t = q, 0
        if kick:
            keys = _key_times(0, ks, lo_gap, hi_gap, rng)
            for t1 in keys[:-1]:
                q = _smooth_segment(out, t, t1, q, space, rng)
                t = t1
            q = _cocked_and_kick(out, t, ks, kick, q, space, rng, None)
            if q is None:
                return None
            t = ks + kick
    while t < size - 1:
        t1 = t + int(rng.integers(lo_gap, hi_gap + 1))
        q = _smooth_segment(out, t, t1, q, space, rng, stop=size - 1)
        t = min(t1, size - 1)
    return out


def _key_times(t0: int, t1: int, lo_gap: int, hi_gap: int, rng: np.random.Generator) -> list[int]:
    """Key sample times after ``t0`` ending exactly at ``t1``; no gap shorter than ``lo_gap``."""
    if t1 <= t0:
        return [t0]
    times = [t0]
    while times[-1] < t1:
        times.append(times[-1] + int(rng.integers(lo_gap, hi_gap + 1)))
    times[-1] = t1
    if len(times) > 2 and times[-1] - times[-2] < lo_gap:
        del times[-2]
    return times[1:]


def _smooth_segment(
    out: np.ndarray,
    t0: int,
    t1: int,
    q0: np.ndarray,
    space: _PostureSpace,
    rng: np.random.Generator,
    stop: int | None = None,
) -> np.ndarray:
    """Fill ``out[t0:t1+1]`` (clipped at ``stop``) moving from q0 to a valid random key."""
    end = t1 if stop is None else min(t1, stop)
    q1, path = q0, np.repeat(q0[None], t1 - t0 + 1, axis=0)  # holding still is always valid
    for _ in range(_ATTEMPTS):
        cand = space.step(q0, rng)
        trial = _min_jerk(q0, cand, t1 - t0)
        if space.valid(trial[: end - t0 + 1]):
            q1, path = cand, trial
            break
    out[t0 : end + 1] = path[: end - t0 + 1]
    return q1 if end == t1 else path[end - t0]


def _start_posture(
    space: _PostureSpace, rng: np.random.Generator, previous: np.ndarray | None
) -> np.ndarray | None:
    """A valid random posture; away from ``previous`` (a jump) when given."""
    for _ in range(_ATTEMPTS * 5):
        cand = space.random_posture(rng)
        if _jumps(cand, previous, space) and space.valid(cand):
            return cand
    return None


def _jumps(q: np.ndarray, previous: np.ndarray | None, space: _PostureSpace) -> bool:
    return previous is None or bool(np.any(np.abs(q - previous) >= _JUMP * space.span))


def _cocked_and_kick(
    out: np.ndarray,
    t0: int,
    ks: int,
    kick: int,
    q0: np.ndarray | None,
    space: _PostureSpace,
    rng: np.random.Generator,
    previous: np.ndarray | None,
) -> np.ndarray | None:
    """Fill ``out[t0:ks+kick+1]``: approach a cocked posture at ``ks``, then sweep (the kick).

    One or two kicking DOFs are brought within ``_COCKED`` of one end of their
    usable range and swept to within ``_COCKED`` of the other end in ``kick``
    sample intervals. With ``q0`` None the sequence starts cocked (``t0 == ks ==
    0``) and the cocked posture must jump away from ``previous``. Returns the
    kicked posture, or None if no valid kick was found.
    """
    for _ in range(_ATTEMPTS * 2):
        n_dofs = 1 if len(space.kickers) == 1 or rng.random() < 0.5 else 2
        dofs = rng.choice(space.kickers, size=n_dofs, replace=False)
        up = rng.random(n_dofs) < 0.5  # sweep towards the upper limit
        near = _COCKED * rng.random(n_dofs)
        far = 1.0 - _COCKED * rng.random(n_dofs)
        cocked = space.random_posture(rng) if q0 is None else space.step(q0, rng)
        cocked[dofs] = space.lo[dofs] + space.span[dofs] * np.where(up, near, 1.0 - near)
        kicked = cocked.copy()
        kicked[dofs] = space.lo[dofs] + space.span[dofs] * np.where(up, far, 1.0 - far)
        if q0 is None:
            if not _jumps(cocked, previous, space):
                continue
            approach = cocked[None]
        else:
            approach = _min_jerk(q0, cocked, ks - t0)
        sweep = _min_jerk(cocked, kicked, kick)
        if space.valid(approach) and space.valid(sweep):
            out[t0 : ks + 1] = approach
            out[ks : ks + kick + 1] = sweep
            return kicked
    return None


# ---- validation --------------------------------------------------------------------------------


def _validate_trajectory(trajectory: np.ndarray, model: KinematicModel) -> np.ndarray:
    q = np.asarray(trajectory, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != len(model.dofs) or len(q) == 0:
        raise ValueError(
            f"trajectory must have shape (T, D) with T >= 1 and D={len(model.dofs)}, "
            f"got {np.shape(trajectory)}"
        )
    if not np.all(np.isfinite(q)):
        raise ValueError("trajectory contains a value that is not a finite number")
    return np.ascontiguousarray(q)


def _validate_offsets(offsets: np.ndarray | None, shape: tuple[int, int, int]) -> np.ndarray | None:
    if offsets is None:
        return None
    out = np.asarray(offsets, dtype=np.float64)
    if out.shape != (*shape, 2) or not np.all(np.isfinite(out)):
        raise ValueError(
            f"marker_offsets_px must be finite numbers of shape (T, V, M, 2) = "
            f"({shape[0]}, {shape[1]}, {shape[2]}, 2), got {np.shape(offsets)}"
        )
    return out


def _validate_frame_size(frame_size: tuple[int, int]) -> tuple[int, int]:
    try:
        width, height = frame_size
    except (TypeError, ValueError):
        raise ValueError(f"frame_size must be (width, height), got {frame_size!r}") from None
    for v in (width, height):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"frame_size must be two positive integers, got {frame_size!r}")
    return int(width), int(height)


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not (
        math.isfinite(value) and value > 0
    ):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(value)


def _non_negative(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not (
        math.isfinite(value) and value >= 0
    ):
        raise ValueError(f"{name} must be a number >= 0, got {value!r}")
    return float(value)


def _grey_level(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not (
        0 <= value <= 255
    ):
        raise ValueError(f"{name} must be a grey level 0..255, got {value!r}")
    return float(value)
