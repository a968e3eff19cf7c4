"""The renderer of paper §3.2: a posture trajectory drawn as the frames a camera would record.

A posture trajectory of a :class:`~core.model.KinematicModel` is projected by a
:class:`~core.rig.Rig` and drawn as bright, anti-aliased round markers on a dark
background with Gaussian noise, one grey frame per video file of the rig. Ghost
markers, occlusions (dropped markers) and interlacing can be added, so that the
whole chain (detection, Eq. 5, annealing) can be measured against the truth.

Pixel coordinates are full-frame (FORMATS §2): u to the right, v down, origin at
the top-left corner of the top-left pixel, pixel centres at +0.5.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from core import _checks
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["render_frames"]

# Background noise: a uniform 16-bit draw mapped through the inverse CDF of the
# rounded, clipped Gaussian (exact up to a CDF step of 2**-16), far cheaper than drawing
# a normal per pixel of every frame. Marker pixels get exact Gaussian noise.
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
    q = _checks.check_trajectory(trajectory, model)
    width, height = _checks.check_frame_size(frame_size)
    n_views, n_markers = len(rig.views), len(model.markers)
    if isinstance(video, bool) or not isinstance(video, int | np.integer) or not (
        0 <= video < rig.n_videos
    ):
        raise ValueError(
            f"video must be a video index 0..{rig.n_videos - 1} of the rig, got {video!r}"
        )
    diameter = _checks.check_positive("marker_diameter_px", marker_diameter_px)
    sigma = _checks.check_non_negative("noise_sigma", noise_sigma)
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
    clips = np.array([_checks.roi_rect(rig, i, width, height) for i in views], dtype=np.float64)
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


def _grey_level(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not (
        0 <= value <= 255
    ):
        raise ValueError(f"{name} must be a grey level 0..255, got {value!r}")
    return float(value)
