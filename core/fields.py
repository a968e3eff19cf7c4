"""De-interlacing: each interlaced frame is two images, its even and its odd field (paper Fig. 1).

A PAL camera exposes the even rows (0, 2, …) and the odd rows of a frame 1/50 s
apart, so a 25 frames/s video holds 50 images/s of a moving animal. Each field
is detected on its own rows, half the frame's height, and its centroids are
mapped back to full-frame pixels (FORMATS §2), so that one rig serves both:
field row ``r`` of parity ``p`` is frame row ``2r + p``, hence
``v_frame = 2·v_field − 0.5 + p`` (pixel centres at +0.5), ``u`` unchanged.

A field samples every other frame row, so a marker a few pixels across covers two
or three of its rows and its weighted centroid locks onto them (up to ±0.28 px in v
on 4 px discs). Where a sharp disc explains a detection's pixels, its centre is fitted
instead (``_detect_kernels.fit_field_discs``), which brings a sharp disc's error to the noise's;
blurred markers keep the centroid (:data:`DISC_MISFIT_MAX`), an imperfect choice that a
model of a blurred disc would serve better. docs/ENGINE_NOTES.md has the measured errors.

Which field is exposed first depends on the camera and the capture chain
(analogue PAL captures are usually even-first, DV is odd-first); it is a
parameter, and decides the order and the timestamps of the two images.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from core import _detect_kernels
from core.detect import DetectorParams, detect_views, view_images
from core.error import Detections
from core.rig import Rig, View

__all__ = ["FIELD_ORDERS", "FIELD_ROW_PITCH", "detect_fields", "field_rig"]

FIELD_ORDERS = ("even-first", "odd-first")
FIELD_ROW_PITCH = 2.0  # a field's rows are this many frame rows apart
# A detection's pixels fit by a sharp disc to within this share of their energy take the
# disc's centre; a larger misfit means a blurred marker, whose centroid is the better guess
# (docs/ENGINE_NOTES.md, "Field centres").
DISC_MISFIT_MAX = 0.003


def field_parities(field_order: str) -> tuple[int, int]:
    """Row parities of the first and second field in time."""
    if field_order not in FIELD_ORDERS:
        raise ValueError(f"field_order must be one of {', '.join(FIELD_ORDERS)}, got {field_order!r}")
    return (0, 1) if field_order == "even-first" else (1, 0)


def field_rig(rig: Rig, parity: int) -> Rig:
    """The rig with every roi restricted to the rows of one field, in field-row coordinates.

    Frame rows ``y .. y+h-1`` hold the field rows ``r`` with ``y <= 2r + parity < y + h``.
    """
    views = []
    for view in rig.views:
        roi = view.roi
        if roi is not None:
            x, y, w, h = roi
            first = -(-(y - parity) // 2)  # ceil((y - parity) / 2)
            stop = -(-(y + h - parity) // 2)
            roi = (x, first, w, max(stop - first, 1))
        views.append(replace(view, roi=roi))
    return Rig(tuple(views))


def detect_fields(
    frames: Sequence[np.ndarray],
    *,
    rig: Rig,
    params: DetectorParams = DetectorParams(),  # frozen: a safe default
    field_order: str = "even-first",
    rigs: tuple[Rig, Rig] | None = None,
) -> tuple[Detections, Detections]:
    """Detections of both fields of one frame per video, in time order, in full-frame pixels.

    Parameters
    ----------
    frames : one (H, W) or (H, W, 3) uint8 frame per video file of the rig.
    field_order : 'even-first' (rows 0, 2, … exposed first) or 'odd-first'.
    rigs : the two :func:`field_rig` of ``rig`` for parities 0 and 1, to skip
        rebuilding them for every frame.
    """
    parities = field_parities(field_order)
    per_parity = rigs if rigs is not None else (field_rig(rig, 0), field_rig(rig, 1))
    views = view_images(frames, rig, params)
    out = []
    for parity in parities:
        fields = [_field_rows(image, view, parity) for image, view in zip(views, rig.views, strict=True)]
        det = detect_views(fields, rig=per_parity[parity], params=params)
        points = det.points.copy()
        points[:, 1] = 2.0 * points[:, 1] - 0.5 + parity
        areas = det.areas * FIELD_ROW_PITCH  # frame pixels
        _fit_discs(fields, per_parity[parity], parity, points, areas, det.start)
        out.append(Detections(points, det.start, areas))
    return out[0], out[1]


def _field_rows(image: np.ndarray, view: View, parity: int) -> np.ndarray:
    """The rows of one field in a view's roi image (:func:`field_rig`'s roi of it), C-contiguous."""
    y = view.roi[1] if view.roi is not None else 0
    return np.ascontiguousarray(image[(parity - y) % 2 :: 2])


def _fit_discs(fields, rig, parity, points, areas, start) -> None:
    """Replace each detection's centroid by its disc-model centre where a sharp disc
    explains its pixels (``_detect_kernels.fit_field_discs``, misfit below :data:`DISC_MISFIT_MAX`).

    fields : each view's field image, as detected.
    """
    radii = np.sqrt(areas / np.pi)
    fitted, misfit = np.empty_like(points), np.empty(len(points))
    for v, view in enumerate(rig.views):
        lo, hi = start[v], start[v + 1]
        if hi == lo:
            continue
        x, first = (view.roi[0], view.roi[1]) if view.roi is not None else (0, 0)
        _detect_kernels.fit_field_discs(fields[v], points[lo:hi], radii[lo:hi], float(x),
                                 FIELD_ROW_PITCH * first + parity, FIELD_ROW_PITCH,
                                 fitted[lo:hi], misfit[lo:hi])
    sharp = misfit < DISC_MISFIT_MAX  # NaN: not fitted
    points[sharp] = fitted[sharp]
