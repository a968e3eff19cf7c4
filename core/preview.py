"""Detection preview: what ``core.detect`` sees in a frame, to choose its settings before a job.

For each view of the rig :func:`preview_frame` draws on a copy of its video's frame:
the roi (a rectangle of :data:`ROI_BGR`, with the view's name and its count of
detections), the binary image after blur, threshold, erosion and dilation
(``core.detect.marker_mask``, tinted :data:`MASK_BGR`: regions the area limits then
refuse are tinted but have no centroid), and each detected centroid (a cross of
:data:`CENTROID_BGR`). The detections are ``core.detect``'s own, so the counts are those
a fit with the same settings starts from (frames, not fields: no de-interlacing).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from core.detect import DetectorParams, detect_views, marker_mask, threshold_level, view_images
from core.error import Detections
from core.rig import Rig

__all__ = ["CENTROID_BGR", "MASK_BGR", "ROI_BGR", "preview_frame"]

ROI_BGR = (0, 255, 255)
MASK_BGR = (0, 0, 255)
CENTROID_BGR = (0, 255, 0)
MASK_OPACITY = 0.5
CROSS_PX = 7
CROSS_GAP_PX = 3


def preview_frame(
    frames: Sequence[np.ndarray], *, rig: Rig, params: DetectorParams = DetectorParams()
) -> tuple[list[np.ndarray], Detections, list[float]]:
    """One frame per video file with each view's roi, mask and centroids drawn; the
    detections; the threshold of each view.

    Parameters
    ----------
    frames : one (H, W) or (H, W, 3) uint8 frame per video file of the rig (BGR).

    Returns
    -------
    drawn : one BGR uint8 (H, W, 3) image per video file.
    detections : ``core.detect.detect`` of ``frames``: one group per view.
    thresholds : the grey level each view was thresholded at (``core.detect.threshold_level``:
        with 'auto' or 'otsu', the one picked in this frame), in view order.
    """
    images = view_images(frames, rig, params)
    detections = detect_views(images, rig=rig, params=params)
    out = [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if f.ndim == 2 else f.copy() for f in frames]
    for v, (view, image) in enumerate(zip(rig.views, images, strict=True)):
        canvas = out[view.video]
        x, y = (view.roi[0], view.roi[1]) if view.roi is not None else (0, 0)
        h, w = image.shape
        if image.size:
            region = canvas[y : y + h, x : x + w]
            mask = marker_mask(image, params).view(bool)
            region[mask] = ((1 - MASK_OPACITY) * region[mask] + MASK_OPACITY * np.array(MASK_BGR)).astype(
                np.uint8)
        cv2.rectangle(canvas, (x, y), (x + w - 1, y + h - 1), ROI_BGR, 1)
        for u, v_ in detections.view(v):
            _cross(canvas, u, v_)
        label = f"{view.name}: {int(detections.counts[v])}"
        at = (x + 4, y + 14)
        cv2.putText(canvas, label, at, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(canvas, label, at, cv2.FONT_HERSHEY_SIMPLEX, 0.45, ROI_BGR, 1, cv2.LINE_AA)
    return out, detections, [threshold_level(image, params) for image in images]


def _cross(image: np.ndarray, u: float, v: float) -> None:
    """A cross on the pixel holding (u, v) (full-frame pixels, FORMATS §2): that pixel, and
    arms from :data:`CROSS_GAP_PX` to :data:`CROSS_PX` away, so the mask around it shows."""
    cu, cv_ = int(np.floor(u)), int(np.floor(v))
    image[cv_, cu] = CENTROID_BGR
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        a = (cu + du * CROSS_GAP_PX, cv_ + dv * CROSS_GAP_PX)
        b = (cu + du * CROSS_PX, cv_ + dv * CROSS_PX)
        cv2.line(image, a, b, CENTROID_BGR, 1, cv2.LINE_8)
