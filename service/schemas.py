"""Pydantic schemas of the API, kept apart from the database models (Create / Public)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from core.detect import MAX_BLUR, MAX_MORPHOLOGY_ITERATIONS
from core.video import MAX_FRAME_PIXELS


def _utc(moment: datetime | None) -> datetime | None:
    """Times are stored in UTC; SQLite hands them back without a zone, so add it."""
    return moment if moment is None or moment.tzinfo else moment.replace(tzinfo=UTC)


UtcDatetime = Annotated[datetime, AfterValidator(_utc)]

# Ids and versions are 32-bit integer columns: a larger number is refused (422), not sent to
# PostgreSQL (where it would fail the query: a 500). Found by tests/service/test_schemathesis.py.
MAX_DB_INT = 2**31 - 1
DbId = Annotated[int, Field(ge=1, le=MAX_DB_INT)]


class DetectorOptions(BaseModel):
    """Marker detection (``core.detect.DetectorParams``)."""

    model_config = ConfigDict(extra="forbid")
    threshold: Annotated[float, Field(ge=0, le=255)] | Literal["otsu"] = 100.0
    channel: Literal["grey", "red", "green", "blue"] = "grey"
    blur: int = Field(default=0, ge=0, le=MAX_BLUR)
    erode: int = Field(default=0, ge=0, le=MAX_MORPHOLOGY_ITERATIONS)
    dilate: int = Field(default=0, ge=0, le=MAX_MORPHOLOGY_ITERATIONS)
    min_area: int = Field(default=2, ge=1, le=MAX_FRAME_PIXELS)  # pixels of a region: at most a frame
    max_area: int = Field(default=2000, ge=1, le=MAX_FRAME_PIXELS)


class JobOptions(BaseModel):
    """Everything besides model, rig and videos that decides a job's result (as ``mocap fit``).

    histogram_version : the model archive version to start from; None: the latest.
    chunk_size : images per chunk task; None: the server's default.
    """

    model_config = ConfigDict(extra="forbid")
    deinterlace: bool = False
    field_order: Literal["even-first", "odd-first"] = "even-first"
    error_threshold_px: float = Field(
        default=1.25, gt=0, allow_inf_nan=False,
        description="Eq. 5 error per compared marker projection (markers x views with any "
                    "detection) above which an image is re-analysed and reported over_threshold; "
                    "the paper's 10 px over 4 markers x 2 views is 1.25 px.")
    max_attempts: int = Field(default=5, ge=1, le=100)
    iterations: int = Field(default=35000, ge=1, le=10_000_000)
    seed: int = Field(default=0, ge=0, lt=2**63)
    chunk_size: int | None = Field(default=None, ge=1, le=1_000_000)
    marker_diameter_px: Annotated[float, Field(ge=0, le=1000)] | Literal["auto"] = Field(
        default="auto", description="markers' diameter in pixels, closer markers may image as one "
        "blob: a number >= 0 (0: the paper's plain Eq. 5) or 'auto' (from the blobs of the first "
        "images, as `mocap fit` does)")
    histogram_version: DbId | None = None
    detector: DetectorOptions = Field(default_factory=DetectorOptions)
    # ---- seeing the fit (service/artifacts.py, docs/SEEING_THE_FIT.md) ----
    overlay: bool = Field(default=False, description="also draw the fit over the video: "
                          "GET /v1/jobs/{id}/artifacts/overlay/... (as `mocap fit --overlay`)")
    plots: bool = Field(default=False, description="also plot angles and histograms: "
                        "GET /v1/jobs/{id}/artifacts/plots/... (as `mocap fit --plots`)")


class ModelPublic(BaseModel):
    id: int
    name: str
    dofs: list[str]
    histogram_versions: int
    created_at: UtcDatetime


class RigPublic(BaseModel):
    id: int
    views: list[str]
    videos: int
    created_at: UtcDatetime


class VideoPublic(BaseModel):
    id: int
    filename: str
    frames: int = Field(description="frames that decode: what a job fits")
    announced_frames: int | None = Field(description="frames the container announces (0: it gives "
                                         "no count); more than frames for a truncated file")
    warning: str | None = Field(description="what is wrong with the file though it can be used, "
                                "e.g. frames announced that do not decode")
    fps: float
    width: int
    height: int
    size_bytes: int
    sha256: str
    created_at: UtcDatetime


NEXT_CURSOR = "pass as ?cursor= for the next page; null: last page"


class ModelPage(BaseModel):
    items: list[ModelPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class RigPage(BaseModel):
    items: list[RigPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class VideoPage(BaseModel):
    items: list[VideoPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class JobCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")
    model_id: DbId
    rig_id: DbId
    video_ids: list[DbId] = Field(min_length=1, max_length=16)
    options: JobOptions = Field(default_factory=JobOptions)


class Trial(BaseModel):
    model_config = ConfigDict(extra="forbid")
    video_ids: list[DbId] = Field(min_length=1, max_length=16)


class BatchCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")
    model_id: DbId
    rig_id: DbId
    trials: list[Trial] = Field(min_length=1, max_length=1000)
    options: JobOptions = Field(default_factory=JobOptions)


class Progress(BaseModel):
    images_total: int
    images_done: int
    images_over_threshold: int
    reanalyses_pending: int
    chunks_total: int
    chunks_done: int


class JobPublic(BaseModel):
    id: int
    status: str
    model_id: int
    rig_id: int
    batch_id: int | None
    trial: int | None
    histogram_version_id: int
    options: dict[str, Any]
    progress: Progress
    error: str | None
    created_at: UtcDatetime
    started_at: UtcDatetime | None
    fitted_at: UtcDatetime | None
    finished_at: UtcDatetime | None


class JobPage(BaseModel):
    items: list[JobPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class BatchPublic(BaseModel):
    id: int
    status: str = Field(description="running until every job is terminal; then succeeded if all "
                                    "succeeded, else failed (or canceled if any was)")
    statuses: dict[str, int]
    progress: Progress
    jobs: list[JobPublic]


# ---- seeing the fit: detection preview (core.preview, docs/SEEING_THE_FIT.md) ----


class DetectPreviewCreate(BaseModel):
    """One frame of an uploaded video through ``core.detect``, with a rig's views of that video."""

    model_config = ConfigDict(extra="forbid")
    rig_id: DbId
    frame: int = Field(default=0, ge=0, le=MAX_DB_INT)
    video_index: int = Field(default=0, ge=0, le=255, description="which of the rig's videos this "
                             "is (its views' `video`); only those views are previewed")
    detector: DetectorOptions = Field(default_factory=DetectorOptions)


class DetectPreview(BaseModel):
    video_id: int
    rig_id: int
    frame: int
    counts: dict[str, int] = Field(description="detections per view, as core.detect (mocap fit) finds them")
    centroids: dict[str, list[list[float]]] = Field(description="(u, v) full-frame pixels per view")
    image: str = Field(description="the frame with rois, thresholded mask and centroids: a PNG data URL")
