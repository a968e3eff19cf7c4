"""Camera rig: one projection per view (paper Eq. 3 generalised; FORMATS §2).

Three projection types map a world point (model units) to full-frame pixels
(u right, v down, pixel centres at +0.5):

- ``affine``: ``(u, v) = A · (x, y, z, 1)``, A 2×4 (orthographic views, mirrors);
- ``pinhole``: OpenCV ``projectPoints`` semantics (Rodrigues ``rvec``, ``tvec``,
  ``K``, distortion ``k1 k2 p1 p2 [k3 [k4 k5 k6]]``);
- ``matrix``: DLT, ``(u, v) = (p1·X / p3·X, p2·X / p3·X)``, P 3×4.

A view sees the part of its video's frame its roi gives, or the whole frame. A rig
read from a file knows its rois; the frames' sizes come with the videos
(:meth:`Rig.framed`). The fit charges a marker projecting outside its view's region as
one the camera could not see (``core._kernels.charged_unseen``).
"""

from __future__ import annotations

import copy
import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from core import _kernels
from core._files import read_bounded
from core._kernels import RigArrays

__all__ = ["MAX_NAME_CHARS", "MAX_RIG_BYTES", "MAX_ROI_PIXELS", "MAX_VIEWS", "Rig", "RigArrays", "RigError",
           "View"]

PROJECTION_TYPES = ("affine", "pinhole", "matrix")
_KIND = {"affine": 0, "pinhole": _kernels.PINHOLE, "matrix": 2}

# Limits on rig files that users upload. A 16-camera pinhole rig takes about 5 kB; the
# limits bound what a hostile file costs (parse time and memory, size of messages).
MAX_RIG_BYTES = 2**20  # bytes of a file or bytes object; characters of a str
MAX_NAME_CHARS = 1024
# Views per rig: every view costs detection and projection in every image. Labs use up to
# about 16 cameras (with mirrors, two views each); a 1 MiB file could otherwise hold 16,000.
MAX_VIEWS = 256
# Largest roi coordinate or side, pixels: the side of the largest frame a video may have
# (core.video.MAX_FRAME_PIXELS is 4096 × 4096; a frame may be long and thin, not longer).
MAX_ROI_PIXELS = 4096 * 4096
# Longer integer literals are read as floats: Python's int() is quadratic in the digits
# and refuses more than 4300 with a plain ValueError; no index or pixel needs 20 digits.
_MAX_INT_DIGITS = 19


class RigError(ValueError):
    """A rig file that cannot be used; the message names the view and the problem."""


@dataclass(frozen=True)
class View:
    """One camera view: which video it is in, where, and how points project into it."""

    name: str
    video: int
    roi: tuple[int, int, int, int] | None
    projection: dict[str, Any]


@dataclass(frozen=True)
class Rig:
    """A validated camera rig. Build it with :meth:`from_json` or :meth:`from_dict`.

    frames : (width, height) of each video's frames, in ``video`` index order, once the
        videos are known (:meth:`framed`); None before.
    """

    views: tuple[View, ...]
    frames: tuple[tuple[int, int], ...] | None = None

    @classmethod
    def from_json(cls, source: str | bytes | Path) -> Rig:
        """Parse and validate ``rig.json`` given as text, bytes or a path (at most :data:`MAX_RIG_BYTES`)."""
        text = read_bounded(source, MAX_RIG_BYTES, "rig file", RigError)
        try:
            data = json.loads(text, parse_constant=_reject_constant, parse_int=_parse_int)
        except RecursionError:
            raise RigError("rig JSON is nested too deeply") from None
        except UnicodeDecodeError as exc:
            raise RigError(f"cannot read rig file: {exc}") from exc
        except json.JSONDecodeError as exc:
            raise RigError(f"rig is not valid JSON: {exc}") from exc
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: Any) -> Rig:
        """Validate a parsed rig document."""
        if not isinstance(data, dict) or not isinstance(data.get("views"), list):
            raise RigError("rig must be an object with a list 'views'")
        if not data["views"]:
            raise RigError("rig has no views")
        if len(data["views"]) > MAX_VIEWS:
            raise RigError(f"rig has {len(data['views'])} views; at most {MAX_VIEWS} are allowed (MAX_VIEWS)")
        views = tuple(_view_from_dict(v, i) for i, v in enumerate(data["views"]))
        dup = [name for name, n in Counter(v.name for v in views).items() if n > 1]
        if dup:
            raise RigError(f"duplicate view name '{sorted(dup)[0]}'")
        _check_video_indices(views)
        return cls(views)

    def to_dict(self) -> dict[str, Any]:
        """The rig as a JSON-ready document; a deep copy, so editing it cannot change the rig."""
        out = []
        for v in self.views:
            d: dict[str, Any] = {"name": v.name, "video": v.video}
            if v.roi is not None:
                d["roi"] = list(v.roi)
            d["projection"] = copy.deepcopy(v.projection)
            out.append(d)
        return {"views": out}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2) + "\n"

    @property
    def n_videos(self) -> int:
        """How many video files the rig expects: its views use video indices 0 .. n_videos - 1."""
        return max(v.video for v in self.views) + 1

    def framed(self, sizes: Sequence[tuple[int, int]], labels: Sequence[str] | None = None) -> Rig:
        """This rig filming videos of frame ``sizes`` ((width, height) each, in ``video``
        index order), checked by :meth:`check_videos` (``labels`` as there)."""
        self.check_videos(sizes, labels)
        return replace(self, frames=tuple((int(w), int(h)) for w, h in sizes))

    @cached_property
    def regions(self) -> np.ndarray:
        """(V, 4) float64: the part of its frame each view sees, (u0, v0, u1, v1) full-frame
        pixels: its roi, else its whole frame (:attr:`frames`), else the whole plane
        (infinite: a frame of unknown size)."""
        out = np.tile([-np.inf, -np.inf, np.inf, np.inf], (len(self.views), 1))
        for k, v in enumerate(self.views):
            if v.roi is not None:
                x, y, w, h = v.roi
                out[k] = (x, y, x + w, y + h)
            elif self.frames is not None:
                out[k, 2:] = self.frames[v.video]
                out[k, :2] = 0.0
        return out

    def check_videos(self, sizes: Sequence[tuple[int, int]], labels: Sequence[str] | None = None) -> None:
        """Refuse videos that do not fit the rig, before any frame is decoded.

        Parameters
        ----------
        sizes : sequence of (width, height), pixels, one per video file given with the job,
            in ``video`` index order (``VideoInfo.width``, ``VideoInfo.height``).
        labels : how messages name each of those videos to the lab (a file name, an upload),
            in the same order; without, "video k".

        Raises
        ------
        RigError
            If the number of videos is not :attr:`n_videos`, a view's roi does not lie inside
            the frame of its video, or a pinhole view's principal point does not (strictly):
            a camera's calibration given another camera's video, of another size (videos in
            the wrong order), which would run the whole job to fit nothing.
        """
        if len(sizes) != self.n_videos:
            raise RigError(f"the rig expects {self.n_videos} video(s), got {len(sizes)}")
        for v in self.views:
            width, height = sizes[v.video]
            video = f"video {v.video}" if labels is None else f"the rig's video {v.video}, {labels[v.video]}"
            if v.roi is not None and (v.roi[0] + v.roi[2] > width or v.roi[1] + v.roi[3] > height):
                raise RigError(
                    f"view '{v.name}': roi {list(v.roi)} lies outside the {width}×{height} frame "
                    f"of {video}"
                )
            if v.projection["type"] == "pinhole":
                cx, cy = v.projection["K"][0][2], v.projection["K"][1][2]
                if not (0 < cx < width and 0 < cy < height):
                    raise RigError(
                        f"view '{v.name}': its principal point ({cx:g}, {cy:g}) lies outside the "
                        f"{width}×{height} frame of {video}: is that video this camera's?"
                    )

    @cached_property
    def arrays(self) -> RigArrays:
        V = len(self.views)
        kind = np.empty(V, dtype=np.int64)
        P = np.zeros((V, 3, 4))
        K = np.tile(np.eye(3), (V, 1, 1))
        dist = np.zeros((V, 8))
        for i, v in enumerate(self.views):
            p = v.projection
            kind[i] = _KIND[p["type"]]
            if p["type"] == "affine":
                P[i, :2] = p["matrix"]
                P[i, 2, 3] = 1.0
            elif p["type"] == "matrix":
                P[i] = p["P"]
            else:
                R, _ = cv2.Rodrigues(np.asarray(p["rvec"], dtype=np.float64))
                P[i, :, :3], P[i, :, 3] = R, p["tvec"]
                K[i] = p["K"]
                coeffs = list(p.get("dist", []))
                dist[i, : len(coeffs)] = coeffs
        return RigArrays(kind, P, K, dist, self.regions)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points into every view.

        Parameters
        ----------
        points : ndarray of shape (M, 3) or (T, M, 3), float64, model units, world frame.

        Returns
        -------
        ndarray of shape (V, M, 2) or (T, V, M, 2), float64, full-frame pixels (u, v).
        """
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim not in (2, 3) or pts.shape[-1] != 3:
            raise ValueError(f"points must have shape (M, 3) or (T, M, 3), got {pts.shape}")
        many = np.ascontiguousarray(pts.reshape((-1, *pts.shape[-2:])))
        out = _kernels.project_many(many, self.arrays)
        return out[0] if pts.ndim == 2 else out


# ---- validation ---------------------------------------------------------------------------


def _reject_constant(name: str) -> float:
    raise RigError(f"rig contains {name}, which is not a number")


def _parse_int(text: str) -> int | float:
    """A JSON integer; one longer than :data:`_MAX_INT_DIGITS` digits as a float (maybe inf)."""
    return int(text) if len(text) <= _MAX_INT_DIGITS else float(text)


def _numeric(value: Any, depth: int) -> bool:
    """True for numbers nested exactly ``depth`` lists/tuples deep, or a numeric array.

    No strings, no booleans; recursion stops at ``depth``, so a list nested a million
    deep costs nothing.
    """
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf"
    if depth > 0:
        return isinstance(value, list | tuple) and all(_numeric(v, depth - 1) for v in value)
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def _matrix(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    if not _numeric(value, len(shape)):
        raise RigError(f"{where} must be a {'×'.join(map(str, shape))} array of numbers")
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise RigError(f"{where} must be a {'×'.join(map(str, shape))} array of numbers") from None
    if arr.shape != shape:
        raise RigError(f"{where} must have shape {'×'.join(map(str, shape))}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise RigError(f"{where} contains a value that is not a finite number")
    return arr


def _view_from_dict(d: Any, index: int) -> View:
    if not isinstance(d, dict):
        raise RigError(f"view {index} must be an object")
    name = d.get("name", f"view{index}")
    if not isinstance(name, str) or not name:
        raise RigError(f"view {index}: 'name' must be a non-empty string")
    if len(name) > MAX_NAME_CHARS:
        raise RigError(f"view {index}: 'name' is {len(name)} characters long; at most {MAX_NAME_CHARS}")
    where = f"view '{name}'"
    video = d.get("video", 0)
    if isinstance(video, bool) or not isinstance(video, int) or video < 0:
        raise RigError(f"{where}: 'video' must be a non-negative integer index, got {video!r}")
    roi = d.get("roi")
    if roi is not None:
        r = _matrix(roi, (4,), f"{where} roi")
        if np.any(r != np.round(r)) or r[0] < 0 or r[1] < 0 or r[2] <= 0 or r[3] <= 0:
            raise RigError(
                f"{where}: roi must be [x, y, width, height], whole numbers, x, y >= 0, width, height > 0"
            )
        if r[0] + r[2] > MAX_ROI_PIXELS or r[1] + r[3] > MAX_ROI_PIXELS or r[2] * r[3] > MAX_ROI_PIXELS:
            raise RigError(
                f"{where}: roi {[int(x) for x in r]} reaches beyond the largest frame a video may have "
                f"({MAX_ROI_PIXELS} pixels, MAX_ROI_PIXELS)"
            )
        roi = tuple(int(x) for x in r)
    proj = d.get("projection")
    if not isinstance(proj, dict) or proj.get("type") not in PROJECTION_TYPES:
        raise RigError(f"{where}: 'projection' must be an object with type affine, pinhole or matrix")
    return View(name, video, roi, _validate_projection(proj, where))


def _check_video_indices(views: tuple[View, ...]) -> None:
    """Views must use video indices 0 .. n-1, none skipped.

    FORMATS §2: ``video`` indexes the list of files given with the job, so the rig
    asks for ``max + 1`` files; a skipped index would be a file no view looks at,
    decoded for nothing — most likely a typo or a view missing from the rig.
    """
    for v in views:  # bounds the index before it sizes anything below
        if v.video >= len(views):
            raise RigError(
                f"view '{v.name}' uses video {v.video}, but a rig of {len(views)} view(s) can use "
                f"videos 0..{len(views) - 1} at most: indices must be 0..n-1 with none skipped"
            )
    used = sorted({v.video for v in views})
    # Sorted distinct indices: the first i with used[i] != i is missing. No range(max + 1):
    # an index of 19 digits would take forever.
    skipped = next((i for i, index in enumerate(used) if index != i), None)
    if skipped is not None:
        raise RigError(
            f"views use video indices {used}: no view uses video {skipped}; "
            "indices must be 0..n-1 with none skipped"
        )


def _validate_projection(p: dict[str, Any], where: str) -> dict[str, Any]:
    kind = p["type"]
    if kind == "affine":
        A = _matrix(p.get("matrix"), (2, 4), f"{where} affine matrix")
        if np.linalg.matrix_rank(A[:, :3]) < 2:
            raise RigError(f"{where}: affine matrix is singular (its 2×3 part has rank < 2)")
        return {"type": kind, "matrix": A.tolist()}
    if kind == "matrix":
        P = _matrix(p.get("P"), (3, 4), f"{where} P")
        if np.linalg.matrix_rank(P[:, :3]) < 3:
            raise RigError(f"{where}: P is singular (its 3×3 part has rank < 3)")
        return {"type": kind, "P": P.tolist()}
    K = _matrix(p.get("K"), (3, 3), f"{where} K")
    # OpenCV's projectPoints has no skew term (it reads fx, fy, cx, cy only): K[0][1] must be 0.
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[0, 1] != 0 or K[1, 0] != 0 or not np.allclose(K[2], [0, 0, 1]):
        raise RigError(f"{where}: K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0 (no skew)")
    dist = p.get("dist", [])
    sequence = isinstance(dist, list | tuple) or (isinstance(dist, np.ndarray) and dist.ndim == 1)
    if not sequence or len(dist) not in (0, 4, 5, 8):
        got = len(dist) if sequence else repr(dist)
        raise RigError(f"{where}: dist must be a list of 0, 4, 5 or 8 coefficients (OpenCV order), got {got}")
    dist_arr = _matrix(dist, (len(dist),), f"{where} dist")
    rvec = _matrix(p.get("rvec"), (3,), f"{where} rvec")
    tvec = _matrix(p.get("tvec"), (3,), f"{where} tvec")
    return {"type": kind, "K": K.tolist(), "dist": dist_arr.tolist(), "rvec": rvec.tolist(),
            "tvec": tvec.tolist()}
