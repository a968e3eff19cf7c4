"""Overlays: the fitted model drawn over the images it was fitted to, so a wrong fit shows.

For every analysed image (a frame, or a field when de-interlaced) and every view of
the rig, :func:`draw` marks on a copy of the view's video frame:

- each detection (``core.detect``, as the fit saw it) as a ring of
  :data:`DETECTION_BGR`;
- the fitted posture's projected markers as filled dots and its segments (joint
  origin to joint origin) as lines, in the colour of the image's mark
  (:data:`MARK_BGR`): ``ok``, ``over_threshold``, or ``ambiguous`` when angles.csv's
  optional ``alternative_deg`` column says another posture fits about as well;
- each marker's name and its distance to the nearest detection of the view (its
  term of Eq. 5), the view's name at its roi, and the frame, field, Eq. 5 error (and per
  compared marker projection, what the threshold is compared with) and mark of the image.

Projections are ``core.model`` forward kinematics and ``core.rig`` projection, with
the root-tracking offsets when the fit tracked the root. :func:`render_overlay`
draws every image of a fitted sequence into one MJPG video per video file, writes the
worst images (by error) and every ambiguous one as PNG files, and a contact sheet of
them, with a manifest naming every file (:data:`MANIFEST`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from core.detect import DetectorParams
from core.error import Detections, fused_marker_diameter, marker_errors
from core.fit import Status
from core.model import KinematicModel
from core.pipeline import FitJob, VideoSource, plan
from core.results import AnglesTable, read_angles_csv
from core.rig import Rig
from core.track import RootTracking

__all__ = [
    "DETECTION_BGR", "MANIFEST", "MARK_BGR", "OVERLAY_DIR", "ImageMarks", "draw", "header", "image_marks",
    "job_from_report", "overlay_job", "render_overlay", "select_images",
]

# Colours, BGR (OpenCV's order). Chosen apart for the common colour-vision deficiencies:
# detections cyan rings; the model green (ok), red (over the threshold), magenta (ambiguous).
DETECTION_BGR = (255, 255, 0)
MARK_BGR = {
    "ok": (0, 200, 0),
    "over_threshold": (0, 0, 255),
    "ambiguous": (255, 0, 255),
    "no_detections": (160, 160, 160),
}
TEXT_BGR = (255, 255, 255)
MARKER_RADIUS_PX = 2
DETECTION_RADIUS_PX = 5
_SHIFT = 4  # OpenCV's fractional bits: marks are drawn at sub-pixel positions
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_FONT_SCALE = 0.4

OVERLAY_DIR = "overlay"  # under a results directory
MANIFEST = "overlay.json"
# Contact sheet, per video file side by side in an image: tiles at most this wide (pixels),
# this many columns, this many tiles (the sheet is held in memory; every selected image is
# also a PNG file of its own). Four cameras make tiles four times as wide, in one column.
TILE_WIDTH_PX = 320
SHEET_COLUMNS = 4
MAX_SHEET_TILES = 48


@dataclass(frozen=True)
class ImageMarks:
    """What is drawn for one analysed image.

    markers : (V, M, 2) float64, full-frame pixels, projected model markers (NaN: no posture).
    joints : (V, J, 2) float64, full-frame pixels, projected joint origins, model-file order.
    errors : (V, M) float64, pixels, ``core.error.marker_errors`` (NaN where nothing to compare).
    mark : key of :data:`MARK_BGR`.
    """

    sample: int
    frame: int
    field: str
    detections: Detections
    markers: np.ndarray
    joints: np.ndarray
    errors: np.ndarray
    error_px: float
    error_per_marker_px: float
    mark: str


def image_marks(
    table: AnglesTable,
    row: int,
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    offsets: np.ndarray | None = None,
) -> ImageMarks:
    """The marks of row ``row`` of angles.csv on its image's ``detections``.

    offsets : (V, 2) float64 pixels added to the view's projections (root tracking), or None.
    """
    dofs = table.dofs[row]
    status = table.statuses[row]
    V, M, J = len(rig.views), len(model.markers), len(model.joints)
    if status is Status.NO_DETECTIONS or not np.all(np.isfinite(dofs)):
        markers, joints = np.full((V, M, 2), np.nan), np.full((V, J, 2), np.nan)
    else:
        markers = rig.project(model.marker_positions(dofs))
        joints = rig.project(np.ascontiguousarray(model.joint_transforms(dofs)[:, :3, 3]))
        if offsets is not None:
            markers, joints = markers + offsets[:, None], joints + offsets[:, None]
    ambiguous = math.isfinite(table.alternative_deg[row])
    return ImageMarks(
        sample=int(table.samples[row]), frame=int(table.frames[row]), field=table.fields[row],
        detections=detections, markers=markers, joints=joints,
        errors=marker_errors(markers, detections), error_px=float(table.errors[row]),
        error_per_marker_px=float(table.error_per_marker[row]),
        mark="ambiguous" if ambiguous else status.value,
    )


def draw(frames: Sequence[np.ndarray], marks: ImageMarks, *, model: KinematicModel,
         rig: Rig) -> list[np.ndarray]:
    """Copies of ``frames`` (one BGR uint8 (H, W, 3) per video file) with ``marks`` drawn.

    A marker projected at (u, v) colours the pixel (floor(u), floor(v)) (FORMATS §2:
    pixel centres at +0.5) and its neighbours within :data:`MARKER_RADIUS_PX`; the dots
    are drawn over every other mark but the image's line of text at the top.
    """
    out = [_bgr(f) for f in frames]
    colour = MARK_BGR[marks.mark]
    parents = _parent_indices(model)
    for v, view in enumerate(rig.views):  # first what the dots may cover
        image = out[view.video]
        x0, y0 = (view.roi[0], view.roi[1]) if view.roi is not None else (0, 0)
        _text(image, view.name, (x0 + 4, y0 + 28))
        for j, p in enumerate(parents):
            if p >= 0:
                _line(image, marks.joints[v, p], marks.joints[v, j], colour)
        for point in marks.detections.view(v):
            cv2.circle(image, _fixed(point), DETECTION_RADIUS_PX << _SHIFT, DETECTION_BGR, 1,
                       cv2.LINE_8, _SHIFT)
        for m, marker in enumerate(model.markers):
            at, error = marks.markers[v, m], marks.errors[v, m]
            if np.all(np.isfinite(at)):
                label = marker.name if not math.isfinite(error) else f"{marker.name} {error:.1f}"
                _text(image, label, (int(at[0]) + 6, int(at[1]) - 4), scale=0.33)
    for v, view in enumerate(rig.views):
        for at in marks.markers[v]:
            if np.all(np.isfinite(at)):
                cv2.circle(out[view.video], _fixed(at), MARKER_RADIUS_PX << _SHIFT, colour, -1,
                           cv2.LINE_8, _SHIFT)
    for image in out:
        _text(image, header(marks), (4, 14), colour=colour)
    return out


def header(marks: ImageMarks) -> str:
    """The image's line of text: frame (field), sample, Eq. 5 error (and per compared marker
    projection, what the threshold is compared with, where angles.csv has it) and mark."""
    field = f" {marks.field}" if marks.field else ""
    error = "-" if not math.isfinite(marks.error_px) else f"{marks.error_px:.2f} px"
    if math.isfinite(marks.error_per_marker_px):
        error += f" ({marks.error_per_marker_px:.2f} per marker)"
    return f"frame {marks.frame}{field}  sample {marks.sample}  error {error}  {marks.mark}"


def _bgr(frame: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame.copy()


def _parent_indices(model: KinematicModel) -> list[int]:
    """Index of each joint's parent in model-file order, -1 for the root."""
    index = {j.name: i for i, j in enumerate(model.joints)}
    return [-1 if j.parent is None else index[j.parent] for j in model.joints]


def _fixed(point: np.ndarray) -> tuple[int, int]:
    """(u, v) full-frame pixels → OpenCV's fixed-point drawing coordinates (pixel centres at 0)."""
    scale = 1 << _SHIFT
    return round(float(point[0] - 0.5) * scale), round(float(point[1] - 0.5) * scale)


def _line(image: np.ndarray, a: np.ndarray, b: np.ndarray, colour: tuple[int, int, int]) -> None:
    if np.all(np.isfinite(a)) and np.all(np.isfinite(b)):
        cv2.line(image, _fixed(a), _fixed(b), colour, 1, cv2.LINE_AA, _SHIFT)


def _text(image: np.ndarray, text: str, at: tuple[int, int], *, colour=TEXT_BGR,
          scale: float = _FONT_SCALE) -> None:
    """Text with a dark outline, legible on bright and dark images."""
    cv2.putText(image, text, at, _FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, text, at, _FONT, scale, colour, 1, cv2.LINE_AA)


# ---- a whole sequence ------------------------------------------------------------------------


def overlay_job(job: FitJob, results: Path, *, worst: int = 12) -> dict[str, Any]:
    """Draw the fit of ``job`` whose outputs are in ``results`` into ``results/overlay``.

    Reads ``results/angles.csv``; tracks the root again when the job did (its offsets
    are not stored), which costs one more detection pass. Returns the manifest.
    """
    table = read_angles_csv(results / "angles.csv")
    offsets = plan(job).offsets if job.root is not None else None
    return render_overlay(table, job.source, results / OVERLAY_DIR, model=job.model,
                          offsets=offsets, worst=worst)


def job_from_report(report: dict[str, Any], videos: Sequence[Path], *, model: KinematicModel,
                    rig: Rig) -> FitJob:
    """The job a ``report.json`` (``core.pipeline.write_outputs``) describes, as far as drawing
    needs it: the videos, de-interlacing, detector, root tracking and the marker diameter
    its source restored cut blobs with (``VideoSource.marker_px``, from the fit's fusion
    distance: the points drawn are those the fit compared with); not the other fit settings."""
    try:
        settings = report["settings"]
        marker_px = fused_marker_diameter(settings["fit"].get("fusion_px", 0.0))
        detector = DetectorParams(**settings["detector"])
        deinterlace = bool(report["deinterlaced"])
        field_order = settings["field_order"] or "even-first"
        root = settings["root_tracking"]
    except (KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"report.json lacks the setting {exc} (not written by mocap fit?)") from None
    if root is not None:
        start = None if root["start"] is None else tuple(tuple(p) for p in root["start"])
        root = RootTracking(root["marker"], start, root["max_jump_px"])
    if len(videos) != rig.n_videos:
        raise ValueError(f"the rig expects {rig.n_videos} video(s), got {len(videos)}")
    source = VideoSource(tuple(videos), rig, detector, deinterlace, field_order, marker_px)
    return FitJob(source, model, root=root)


def select_images(table: AnglesTable, worst: int) -> list[int]:
    """Rows to show: the ``worst`` largest errors, largest first, then every ambiguous row."""
    if worst < 0:
        raise ValueError(f"worst must be >= 0, got {worst}")
    finite = np.flatnonzero(np.isfinite(table.errors))
    ranked = finite[np.argsort(-table.errors[finite], kind="stable")][:worst].tolist()
    ambiguous = np.flatnonzero(np.isfinite(table.alternative_deg)).tolist()
    return ranked + [r for r in ambiguous if r not in set(ranked)]


def render_overlay(
    table: AnglesTable,
    source: VideoSource,
    out: Path,
    *,
    model: KinematicModel,
    offsets: np.ndarray | None = None,
    worst: int = 12,
) -> dict[str, Any]:
    """Draw every image of a fitted sequence; write the videos, images, sheet and manifest.

    Parameters
    ----------
    table : the sequence's angles.csv, one row per image of ``source`` in sample order.
    source : the videos the sequence was fitted from, with the fit's detector settings.
    out : directory for ``video<k>.avi`` (MJPG, one per video file, one image per analysed
        image), ``images/sample_<n>.png`` (each selected image, its video files side by
        side), ``contact_sheet.png`` and :data:`MANIFEST`.
    offsets : (N, V, 2) root-tracking offsets of the fit, or None.
    worst : how many of the largest errors to select (and every ambiguous image).

    Returns
    -------
    The manifest, also written as ``out/overlay.json``.
    """
    n = len(source)
    if len(table.samples) != n or not np.array_equal(table.samples, np.arange(n)):
        raise ValueError(f"angles.csv has {len(table.samples)} images, the videos give {n}: "
                         "not the videos of this fit (or not the same de-interlacing)")
    if table.dof_names != model.dof_names:
        raise ValueError(f"angles.csv has DOF columns {table.dof_names}, the model {model.dof_names}")
    chosen = select_images(table, worst)
    wanted = set(chosen)
    (out / "images").mkdir(parents=True, exist_ok=True)
    writers: list[cv2.VideoWriter] = []
    tiles: dict[int, np.ndarray] = {}
    fps = source.fps * source.per_frame
    sample = 0
    try:
        for frames, images in source.decoded(0, n // source.per_frame):
            if not writers:
                writers = [_writer(out / f"video{k}.avi", f, fps) for k, f in enumerate(frames)]
            for det in images:
                marks = image_marks(table, sample, det, model=model, rig=source.rig,
                                    offsets=None if offsets is None else offsets[sample])
                drawn = draw(frames, marks, model=model, rig=source.rig)
                for writer, image in zip(writers, drawn, strict=True):
                    writer.write(image)
                if sample in wanted:
                    side = _side_by_side(drawn)
                    cv2.imwrite(str(out / "images" / _image_name(sample)), side)
                    if len(tiles) < MAX_SHEET_TILES // len(drawn):
                        tiles[sample] = _tile(side, header(marks), MARK_BGR[marks.mark], len(drawn))
                sample += 1
    finally:
        for writer in writers:
            writer.release()
    sheet = [tiles[r] for r in chosen if r in tiles]
    if sheet:
        cv2.imwrite(str(out / "contact_sheet.png"), _sheet(sheet, len(writers)))
    manifest = _manifest(table, chosen, writers, sheet, worst)
    (out / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def _manifest(table: AnglesTable, chosen: list[int], writers: list, sheet: list,
              worst: int) -> dict[str, Any]:
    def row(r: int) -> dict[str, Any]:
        alt = table.alternative_deg[r]
        return {
            "sample": int(table.samples[r]), "frame": int(table.frames[r]), "field": table.fields[r],
            "error_px": None if not math.isfinite(table.errors[r]) else float(table.errors[r]),
            "status": table.statuses[r].value, "attempts": int(table.attempts[r]),
            "alternative_deg": None if not math.isfinite(alt) else float(alt),
            "file": f"images/{_image_name(int(table.samples[r]))}",
        }

    return {
        "videos": [f"video{k}.avi" for k in range(len(writers))],
        "contact_sheet": "contact_sheet.png" if sheet else None,
        "sheet_images": len(sheet),
        "worst": worst,
        "images": [row(r) for r in chosen],
        "marks": {"detection_bgr": list(DETECTION_BGR),
                  **{f"{k}_bgr": list(c) for k, c in MARK_BGR.items()}},
    }


def _image_name(sample: int) -> str:
    return f"sample_{sample:06d}.png"


def _writer(path: Path, frame: np.ndarray, fps: float) -> cv2.VideoWriter:
    height, width = frame.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (width, height))
    if not writer.isOpened():
        raise OSError(f"cannot write the overlay video {path.name}")
    return writer


def _side_by_side(images: list[np.ndarray]) -> np.ndarray:
    """The images of one sample's video files in one row (shorter ones padded black)."""
    height = max(i.shape[0] for i in images)
    padded = [np.pad(i, ((0, height - i.shape[0]), (0, 0), (0, 0))) for i in images]
    return np.concatenate(padded, axis=1)


def _tile(image: np.ndarray, caption: str, colour: tuple[int, int, int], videos: int) -> np.ndarray:
    """The image (``videos`` frames side by side) scaled to at most :data:`TILE_WIDTH_PX` wide
    a frame, its caption legible above it."""
    scale = min(1.0, videos * TILE_WIDTH_PX / image.shape[1])
    size = (round(image.shape[1] * scale), max(1, round(image.shape[0] * scale)))
    small = cv2.resize(image, size, interpolation=cv2.INTER_AREA) if scale < 1.0 else image
    tile = np.zeros((small.shape[0] + 20, small.shape[1], 3), dtype=np.uint8)
    tile[20:] = small
    _text(tile, caption, (4, 14), colour=colour)
    return tile


def _sheet(tiles: list[np.ndarray], videos: int) -> np.ndarray:
    """Tiles of ``videos`` frames side by side in a grid of :data:`SHEET_COLUMNS` columns for
    one frame a tile, fewer for more (one from four on), fewer if there are fewer tiles; each
    cell the largest tile's size."""
    h = max(t.shape[0] for t in tiles)
    w = max(t.shape[1] for t in tiles)
    columns = min(max(1, SHEET_COLUMNS // videos), len(tiles))
    rows = -(-len(tiles) // columns)
    sheet = np.zeros((rows * h, columns * w, 3), dtype=np.uint8)
    for i, t in enumerate(tiles):
        r, c = divmod(i, columns)
        sheet[r * h : r * h + t.shape[0], c * w : c * w + t.shape[1]] = t
    return sheet
