"""Marker detection: image → 2D marker centroids per view (paper Fig. 1).

For every view of the rig, its roi is cut from its video's frame and passed
through the filter chain of the paper: channel selection → Gaussian blur →
threshold → erosion → dilation. The 8-connected regions of the binary image
whose area lies within ``[min_area, max_area]`` are the markers; each is
located by an intensity-weighted, sub-pixel centroid.

Centroid weights. Weighting pixels by ``intensity - threshold`` over the
thresholded region only (the common recipe) drops the dim, partly covered edge
pixels of a small marker unevenly: 0.03 px RMS, up to 0.065 px, on 4 px markers
without noise. Here
a region is grown by one pixel (so every partly covered pixel is counted), the
local background is the mean intensity of the ring of pixels two pixels away
from the region, and the weights are ``intensity - local background`` (not
clipped, so zero-mean noise stays unbiased). On the synthetic renderer's 4 px
markers this recovers the projection to 0.007 px RMS (max 0.013 px, the bias of
pixel sampling itself) without noise, and 0.013 px RMS (max 0.04 px) with
noise σ = 2 grey levels. Intensities are those of the selected channel
before blurring. Pixel centres are at +0.5 and the result is in full-frame
pixels (FORMATS §2).
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from core import _detect_kernels
from core.bounds import OptionError, check_options, option
from core.error import Detections
from core.rig import Rig
from core.video import MAX_FRAME_PIXELS

__all__ = [
    "CHANNELS", "DetectorParams", "auto_threshold", "detect", "detect_views", "marker_diameter",
    "marker_mask", "restored_at_edges", "threshold_level", "view_images",
]

# OpenCV's threads per process, set when this module is imported. One: the filters run on
# a view's roi (a few hundred kB), where OpenCV's thread pool costs more than it saves, and
# processes are the unit of parallelism (`mocap fit --jobs N`, one service worker per core),
# as for decoding (``core.video.DECODE_THREADS``; docs/ENGINE_NOTES.md, "Threads").
# OpenCV has no per-call setting; a program embedding core that wants OpenCV's pool for
# its own work calls cv2.setNumThreads after importing core.
OPENCV_THREADS = 1
cv2.setNumThreads(OPENCV_THREADS)

CHANNELS = ("grey", "red", "green", "blue")
_BGR_INDEX = {"blue": 0, "green": 1, "red": 2}
_KERNEL3 = np.ones((3, 3), dtype=np.uint8)
# Bounds of the filter parameters: each costs time per pixel of every view and image
# (erosion and dilation passes, the blur kernel's side), and the areas go to the compiled
# labelling as 64-bit integers. Markers are a few pixels across; these are far beyond.
MAX_MORPHOLOGY_ITERATIONS = 20
MAX_BLUR = 99
_BISECTIONS = 31  # halvings of [-1, 1] that place a cut disc's centre to 1e-9 of its radius


@dataclass(frozen=True)
class DetectorParams:
    """Parameters of the detection filter chain (paper Fig. 1), validated on creation.

    Attributes
    ----------
    channel : {'grey', 'red', 'green', 'blue'}, default 'grey'
        Intensity used. Colour frames are BGR (as OpenCV reads them); 'grey'
        converts them with ``cv2.COLOR_BGR2GRAY``; 'red', 'green' and 'blue'
        need colour frames.
    threshold : float in [0, 255], 'otsu' or 'auto', default 'auto'
        A pixel belongs to a marker if its (blurred) intensity is greater than
        this; 'otsu' picks it per view and image (Otsu's method), which suits
        images that contain markers; 'auto' per view and image from the
        background's level and noise and the markers' level (:func:`auto_threshold`):
        a fixed level sees a lit background as one region and misses markers
        dimmed by motion blur.
    erode, dilate : int >= 0, default 0
        Iterations of binary erosion, then dilation, with a 3×3 kernel
        (erode then dilate removes speckles smaller than the markers).
    blur : int, default 0
        0 for none, else the odd size of a Gaussian kernel applied before the threshold.
    min_area, max_area : int, default 2, 2000
        Pixels of a region (after erosion and dilation) for it to count as a marker.
    """

    channel: str = option("grey", kind=str, words=CHANNELS, help="intensity used (colour frames: BGR)")
    threshold: float | str = option("auto", ge=0, le=255, words=("otsu", "auto"),
                                    help="a pixel brighter than this grey level is a marker's; 'otsu': "
                                         "picked per view and image; 'auto': per view and image, "
                                         "from its background's level and noise and its markers' level")
    erode: int = option(0, kind=int, ge=0, le=MAX_MORPHOLOGY_ITERATIONS,
                        help="erosion iterations after the threshold")
    dilate: int = option(0, kind=int, ge=0, le=MAX_MORPHOLOGY_ITERATIONS,
                         help="dilation iterations after erosion")
    blur: int = option(0, kind=int, ge=0, le=MAX_BLUR,
                       help="Gaussian blur kernel before the threshold (0: none, else odd)")
    min_area: int = option(2, kind=int, ge=1, le=MAX_FRAME_PIXELS, help="smallest marker region, pixels")
    max_area: int = option(2000, kind=int, ge=1, le=MAX_FRAME_PIXELS,
                           help="largest marker region, pixels (>= min_area)")

    def __post_init__(self) -> None:
        check_options(self)
        if self.blur and self.blur % 2 == 0:
            raise OptionError("blur", f"must be 0 (none) or an odd kernel size, got {self.blur!r}")
        if self.max_area < self.min_area:
            raise OptionError("max_area", f"must be >= min_area ({self.min_area}), got {self.max_area!r}")


def detect(
    frames: Sequence[np.ndarray],
    *,
    rig: Rig,
    params: DetectorParams = DetectorParams(),  # frozen: a safe default
) -> Detections:
    """Detect marker centroids in every view of one image (one frame per video file).

    Parameters
    ----------
    frames : sequence of ndarray of shape (H, W) or (H, W, 3), uint8
        One frame per video file of the rig (``rig.n_videos``), in video index
        order; colour frames in BGR order. Frames of different videos may differ in size.
    rig : Rig
        Views to detect in: each view's roi (x, y, width, height) of its video's
        frame, or the whole frame without roi.
    params : DetectorParams

    Returns
    -------
    Detections
        One group per rig view, in rig order: (N_v, 2) float64 centroids (u, v)
        in full-frame pixels, pixel centres at +0.5, regions in raster order of
        their first pixel.

    Raises
    ------
    ValueError
        If the number of frames is not ``rig.n_videos``, a frame is not uint8
        (H, W) or (H, W, 3), a colour channel is asked of a grey frame, or a roi
        lies outside its frame.
    """
    return detect_views(view_images(frames, rig, params), rig=rig, params=params)


def view_images(
    frames: Sequence[np.ndarray], rig: Rig, params: DetectorParams
) -> list[np.ndarray]:
    """Each view's roi of its frame in ``params.channel`` (:func:`view_image`), frames checked.

    What :func:`detect_views` reads: de-interlacing cuts its fields from these, so
    that each roi is converted once per frame however many images it gives.
    """
    if not isinstance(params, DetectorParams):
        raise ValueError(f"params must be a DetectorParams, got {type(params).__name__}")
    frames = _validate_frames(frames, rig)
    return [view_image(frames, rig, v, params.channel) for v in range(len(rig.views))]


def detect_views(images: Sequence[np.ndarray], *, rig: Rig, params: DetectorParams) -> Detections:
    """Detections in each view's (h, w) uint8 image, its roi of ``rig`` already cut
    (:func:`view_images`); centroids in the frame pixels of ``rig``."""
    found = [_detect_view(image, params, rig, v) for v, image in enumerate(images)]
    return Detections._of_views([f[0] for f in found], [f[1] for f in found])


# ---- per view ------------------------------------------------------------------------------


def marker_diameter(images: Iterable[Detections]) -> float | None:
    """Typical marker diameter in pixels: a disc of the median detected region's area.

    The median, over every detection of every image, ignores the few fused blobs and
    ghosts. The diameter sets how close two markers' projections must be to image as
    one blob (``core.error.fusion_distance``); a lab knows its marker size in
    millimetres, rarely in pixels. None when no image has detections with areas.

    >>> one = Detections.from_views([np.zeros((3, 2))], areas=[np.array([12.0, 13.0, 30.0])])
    >>> round(marker_diameter([one]), 3)
    4.068
    """
    areas = [d.areas for d in images if d.areas is not None and len(d.areas)]
    if not areas:
        return None
    return 2.0 * float(np.sqrt(np.median(np.concatenate(areas)) / np.pi))


def restored_at_edges(det: Detections, rig: Rig, diameter_px: float) -> Detections:
    """``det`` with each blob that its view's edge cuts moved to the centre of the marker's
    disc (diameter ``diameter_px``) it is a part of.

    A marker whose disc crosses the edge of its view's region (``Rig.regions``: its roi,
    else its frame) shows only the part inside, and that part's centroid lies inside the
    disc's centre: by 0.42 of the radius where the centre is on the edge, by up to the
    radius where a sliver shows. Eq. 5 charged the true posture that bias, and a wrong
    posture that put the marker deeper inside scored lower. Across the edge the centroid's
    depth ``g`` from it gives the centre's depth ``d`` exactly for a disc
    (:func:`_disc_centre_depth`); along the edge the centroid is unbiased.

    A whole disc's centroid lies at least a radius from every edge, so a blob whose centroid
    lies nearer is a cut disc, or a blob smaller than a marker (moved at most 0.42 radii
    outward). Blobs that may be merged markers (``Detections.kernel_points``) are left
    where they are, as is every blob where ``diameter_px`` is 0 (no marker size known)
    and wherever the region has no edge (a frame of unknown size).
    """
    radius = 0.5 * diameter_px
    if radius <= 0 or not len(det.points):
        return det
    regions = rig.regions[np.repeat(np.arange(det.n_views), det.counts)]  # (N, 4)
    before, after = det.points - regions[:, :2], regions[:, 2:] - det.points  # (N, 2) depths
    depth = np.minimum(before, after)
    cut = (depth >= 0) & (depth < radius) & (det.kernel_points[:, 2:] == 0)
    if not cut.any():
        return det
    outward = np.where(after < before, 1.0, -1.0)
    shift = depth - radius * _disc_centre_depth(np.clip(depth / radius, 0.0, 1.0))
    points = det.points + np.where(cut, outward * shift, 0.0)
    return Detections(points, det.start, det.areas)


def _disc_centre_depth(seen: np.ndarray) -> np.ndarray:
    """The depth inside an edge of a unit disc's centre (in [-1, 1]; negative: beyond it)
    whose part inside has its centroid at depth ``seen`` (in [0, 1]), elementwise.

    The part of a unit disc at depth ``t`` inside the edge has area
    ``A = t sqrt(1 - t^2) + asin(t) + pi / 2`` and its centroid lies ``(2/3) (1 - t^2)^1.5 / A``
    deeper than the centre; that depth grows with ``t`` from 0 (t = -1) to 1 (t = 1), and is
    inverted by bisection to 1e-9.
    """
    low, high = np.full(seen.shape, -1.0), np.full(seen.shape, 1.0)
    for _ in range(_BISECTIONS):
        t = 0.5 * (low + high)
        chord = np.sqrt(1.0 - t * t)
        deeper = t + (2.0 / 3.0) * chord**3 / (t * chord + np.arcsin(t) + 0.5 * np.pi) > seen
        high, low = np.where(deeper, t, high), np.where(deeper, low, t)
    return 0.5 * (low + high)


def view_image(frames: Sequence[np.ndarray], rig: Rig, index: int, channel: str) -> np.ndarray:
    """The roi of a view's frame in the selected channel: (h, w) uint8, C-contiguous.

    The roi is converted, not the frame: rois often cover a fraction of it.
    """
    view = rig.views[index]
    frame = frames[view.video]
    height, width = frame.shape[:2]
    crop = frame
    if view.roi is not None:
        x, y, w, h = view.roi
        if x + w > width or y + h > height:
            raise ValueError(
                f"roi {list(view.roi)} of view '{view.name}' lies outside its "
                f"{width}×{height} frame (video {view.video})"
            )
        crop = frame[y : y + h, x : x + w]
    if crop.ndim == 2:
        if channel != "grey":
            raise ValueError(
                f"channel {channel!r} needs colour (H, W, 3) frames; "
                f"video {view.video} is grey (use channel='grey')"
            )
        return np.ascontiguousarray(crop)
    if channel == "grey":
        return cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY)
    return np.ascontiguousarray(crop[:, :, _BGR_INDEX[channel]])


def marker_mask(image: np.ndarray, params: DetectorParams) -> np.ndarray:
    """The binary image of one view's (h, w) uint8 image after blur, threshold, erosion and
    dilation: (h, w) uint8, 1 where a pixel may belong to a marker (before the area filter).

    What detection labels, and what ``core.preview`` draws.
    """
    work = _blurred(image, params)
    _, binary = cv2.threshold(work, _level(work, params), 1, cv2.THRESH_BINARY)
    if params.erode:
        binary = cv2.erode(binary, _KERNEL3, iterations=params.erode)
    if params.dilate:
        binary = cv2.dilate(binary, _KERNEL3, iterations=params.dilate)
    return binary


def threshold_level(image: np.ndarray, params: DetectorParams) -> float:
    """The grey level :func:`marker_mask` thresholds one view's (h, w) uint8 image at: the
    fixed one, or the one 'otsu' or 'auto' picks for this image (after the blur), so that
    a lab sees what 'auto' chose (``mocap detect`` prints it)."""
    return _level(_blurred(image, params), params)


def _blurred(image: np.ndarray, params: DetectorParams) -> np.ndarray:
    return cv2.GaussianBlur(image, (params.blur, params.blur), 0) if params.blur > 1 else image


def _level(work: np.ndarray, params: DetectorParams) -> float:
    """The threshold of the blurred view image ``work``: a pixel above it is a marker's."""
    if params.threshold == "otsu":
        return float(cv2.threshold(work, 0, 1, cv2.THRESH_BINARY | cv2.THRESH_OTSU)[0])
    return auto_threshold(work) if params.threshold == "auto" else float(params.threshold)


AUTO_NOISE_SIGMAS = 6.0  # 'auto': the threshold lies this many noise deviations above the background
AUTO_MIN_CONTRAST = 30.0  # grey levels above the background at least (a noise-free background)
AUTO_MARKER_SHARE = 1e-4  # of a view's pixels, the brightest: the markers' level
AUTO_MARKER_PIXELS = 20  # at least this many of the brightest pixels (a small view)
AUTO_MARKER_FRACTION = 0.25  # of the way from the background up to the markers' level


def auto_threshold(image: np.ndarray) -> float:
    """The 'auto' threshold of one view's (h, w) uint8 image (grey levels): its background
    level, the median (markers cover a small share of a view), plus the largest of
    :data:`AUTO_MARKER_FRACTION` of the way up to the markers' level (the level of the
    brightest :data:`AUTO_MARKER_SHARE` of the pixels, at least :data:`AUTO_MARKER_PIXELS`),
    :data:`AUTO_NOISE_SIGMAS` times the background's noise (1.4826 × the median absolute
    deviation, a standard deviation that the markers do not inflate) and
    :data:`AUTO_MIN_CONTRAST`; at most 254.

    Why: a fixed level fails both ways. A lit background above it becomes one region,
    larger than any marker, and is dropped; markers that motion blur spreads over a few
    pixels fall under it. A quarter of the way up keeps bright markers' blobs as narrow as
    a fixed level does, where a level just above the noise widened them and cost the
    spider's clean footage accuracy, and stays under a
    blurred marker's level where others are sharp (half way up lost them;
    docs/BENCH_SUBJECTS.md, footage). Read from the image's histogram (OpenCV's: under a
    millisecond on a megapixel view)."""
    if image.size == 0:
        return 254.0
    counts = cv2.calcHist([image], [0], None, [256], [0, 256]).ravel()
    cumulative = np.cumsum(counts)
    half = image.size / 2.0
    background = int(np.searchsorted(cumulative, half))
    spread = np.abs(np.arange(256) - background)
    order = np.argsort(spread, kind="stable")
    deviation = float(spread[order][np.searchsorted(np.cumsum(counts[order]), half)])
    brightest = max(AUTO_MARKER_PIXELS, AUTO_MARKER_SHARE * image.size)
    markers = int(np.searchsorted(cumulative, max(image.size - brightest, 0.0)))
    above = max(AUTO_MARKER_FRACTION * (markers - background), AUTO_NOISE_SIGMAS * 1.4826 * deviation,
                AUTO_MIN_CONTRAST)
    return min(background + above, 254.0)


def _detect_view(
    image: np.ndarray, params: DetectorParams, rig: Rig, index: int
) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) float64 full-frame centroids of the marker regions of one view's image, and
    their (N,) areas in pixels (none in an empty image: a one-row roi has no rows of one field)."""
    if image.size == 0:
        return np.empty((0, 2)), np.empty(0)
    binary = marker_mask(image, params)
    pixels = np.flatnonzero(binary.view(bool))
    centroids, areas = _detect_kernels.detect_regions(image, binary, pixels, params.min_area,
                                               params.max_area, _scratch(binary.size))
    roi = rig.views[index].roi
    if roi is not None:
        centroids += (roi[0], roi[1])
    return centroids, areas


@functools.lru_cache(maxsize=8)
def _scratch(size: int) -> np.ndarray:
    """Per-size scratch for the labelling kernel (one process fits one rig's few roi sizes)."""
    return np.empty(size, dtype=np.int32)


# ---- validation ----------------------------------------------------------------------------


def _validate_frames(frames: Sequence[np.ndarray], rig: Rig) -> list[np.ndarray]:
    n_videos = rig.n_videos
    single = isinstance(frames, np.ndarray) and (
        frames.ndim == 2 or (frames.ndim == 3 and frames.shape[2] == 3 and len(frames) != n_videos)
    )
    if single or not hasattr(frames, "__len__"):
        raise ValueError(
            f"frames must be a sequence with one frame per video file of the rig "
            f"({n_videos}); to detect in a single frame pass [frame]"
        )
    if len(frames) != n_videos:
        raise ValueError(
            f"frames must hold one frame per video file of the rig: the rig has "
            f"{n_videos} video(s), got {len(frames)} frame(s)"
        )
    out = []
    for i, frame in enumerate(frames):
        f = np.asarray(frame)
        if f.dtype != np.uint8 or not (f.ndim == 2 or (f.ndim == 3 and f.shape[2] == 3)):
            raise ValueError(
                f"frame {i} must be a uint8 array (H, W) or (H, W, 3), got {f.dtype} {f.shape}"
            )
        out.append(f)
    return out
