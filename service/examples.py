"""Examples of the API's JSON bodies for its OpenAPI description (``/docs``, ``/redoc``): one per
schema, consistent with each other (the locust example of ``core/examples/locust_hind_leg``)."""

from __future__ import annotations

from typing import Any

CREATED = "2026-11-24T09:30:00Z"
METADATA = {"subject": "locust 7", "condition": "walking", "temperature_c": 24.5}
DETECTOR = {"threshold": "auto", "channel": "grey", "blur": 0, "erode": 0, "dilate": 0, "min_area": 2,
            "max_area": 2000}
FIT_OPTIONS = {"deinterlace": False, "field_order": "even-first", "error_threshold_px": 1.25,
               "max_attempts": 5, "iterations": 35000, "seed": 0, "chunk_size": None,
               "marker_diameter_px": 4.0, "detector": DETECTOR, "prior_weight": 100.0,
               "root_marker": None, "root_start": None, "root_max_jump_px": 20.0}
OPTIONS = {**FIT_OPTIONS, "histogram_version": None, "overlay": False, "plots": False}
PROGRESS = {"images_total": 200, "images_done": 120, "images_over_threshold": 2, "reanalyses_pending": 0,
            "chunks_total": 4, "chunks_done": 2}
RIG = {"views": [
    {"name": "side", "video": 0, "roi": [0, 0, 360, 288],
     "projection": {"type": "affine", "matrix": [[3.0, 0, 0, 240], [0, -3.0, 0, 184]]}},
    {"name": "top", "video": 0, "roi": [0, 288, 360, 288],
     "projection": {"type": "affine", "matrix": [[3.0, 0, 0, 240], [0, 0, 3.0, 438]]}}]}
MODEL_XML = """<model name="locust_hind_leg" units="mm">
  <joint name="body_coxa">
    <offset x="0" y="0" z="0"/>
    <dof axis="y" name="phi" min="120" max="220"/>
  </joint>
  <marker name="m0" joint="body_coxa"><offset x="0" y="0" z="0"/></marker>
</model>
"""

MODEL = {"id": 1, "name": "locust_hind_leg", "dofs": ["phi", "psi", "alpha", "beta", "gamma"],
         "histogram_versions": 1, "sha256": "9f2c" + "0" * 60, "metadata": METADATA, "created_at": CREATED}
EXISTING = {"model_id": 1, "histogram_versions": 3, "latest_version": 3}
MODEL_CREATED = {**MODEL, "id": 2, "existing_model_id": 1, "existing": EXISTING, "reused": False,
                 "warnings": []}
RIG_PUBLIC = {"id": 1, "name": "two mirrors", "metadata": {"calibrated": "2026-11-20"},
              "views": ["side", "top"], "videos": 1, "created_at": CREATED}
VIDEO = {"id": 1, "filename": "trial1_cam0.avi", "name": "walk-07", "metadata": METADATA, "frames": 200,
         "announced_frames": 200, "warning": None, "fps": 50.0, "width": 720, "height": 576,
         "size_bytes": 82944000, "sha256": "3b1a" + "0" * 60, "created_at": CREATED}
JOB = {"id": 7, "status": "running", "model_id": 1, "rig_id": 1, "batch_id": None, "trial": None,
       "name": "walk-07", "metadata": METADATA, "histogram_version_id": 1, "options": OPTIONS,
       "progress": PROGRESS, "error": None, "created_at": CREATED, "started_at": CREATED, "fitted_at": None,
       "finished_at": None}
JOB_CREATE = {"model_id": 1, "rig_id": 1, "video_ids": [1], "options": {"marker_diameter_px": 4.0},
              "name": "walk-07", "metadata": METADATA}
TRIALS = [{"video_ids": [1], "name": "walk", "metadata": {"speed": "slow"}},
          {"video_ids": [2], "name": "walk", "metadata": {"speed": "fast"}}]
BATCH_CREATE = {"model_id": 1, "rig_id": 1, "options": {"marker_diameter_px": 4.0}, "name": "day 3",
                "metadata": {"experimenter": "AB"}, "trials": TRIALS}
BATCH = {"id": 3, "name": "day 3", "metadata": {"experimenter": "AB"}, "status": "running",
         "statuses": {"running": 1, "succeeded": 1}, "progress": PROGRESS,
         "jobs": [{**JOB, "batch_id": 3, "trial": 0, "name": "walk", "metadata": {"speed": "slow"}}]}
PREVIEW_CREATE = {"rig_id": 1, "frame": 0, "video_index": 0, "detector": DETECTOR}
PREVIEW = {"video_id": 1, "rig_id": 1, "frame": 0, "counts": {"side": 4, "top": 4},
           "thresholds": {"side": 72.25, "top": 72.0},
           "centroids": {"side": [[240.0, 184.0], [279.0, 184.0], [352.1, 180.3], [420.6, 176.2]],
                         "top": [[240.0, 438.0], [279.0, 438.0], [352.1, 441.5], [420.6, 444.9]]},
           "image": "data:image/png;base64,iVBORw0KGgo..."}
PROBLEM = {"detail": "video 3 is used by job(s) 7, 9; an upload a job names (finished or not) cannot be "
                     "deleted: its results and archive refer to it"}
REPORT = {"images": 200, "status": {"ok": 196, "over_threshold": 2, "no_detections": 2},
          "error_per_marker_px": {"mean": 0.31, "median": 0.27, "p95": 0.74, "max": 2.1},
          "videos": [{"id": 1, "filename": "trial1_cam0.avi", "name": "walk-07", "metadata": METADATA,
                      "frames": 200, "announced_frames": 200, "warning": None}],
          "job": {"id": 7, "name": "walk-07", "metadata": METADATA, "trial": None}, "batch": None,
          "model": {"id": 1, "name": "locust_hind_leg", "metadata": None},
          "rig": {"id": 1, "name": "two mirrors", "metadata": {"calibrated": "2026-11-20"}},
          "service": {"job_id": 7, "chunks": 4, "workers": ["celery@lab1"], "histogram_version_id": 1,
                      "attempts_total": 212}}
ARTIFACTS = ["overlay/contact_sheet.png", "overlay/video0.avi", "plots/angles.svg"]


def page(item: dict[str, Any]) -> dict[str, Any]:
    """A listing's page holding ``item``, with the cursor of the next page."""
    return {"items": [item], "next_cursor": item["id"]}


def example(value: Any) -> dict[str, Any]:
    """``json_schema_extra`` giving a schema ``value`` as its example."""
    return {"examples": [value]}
