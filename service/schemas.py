"""Pydantic schemas of the API, kept apart from the database models (Create / Public)."""

from __future__ import annotations

import dataclasses
import json
import math
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, create_model

from core.bounds import Bounds, bounds_of
from core.detect import DetectorParams
from core.options import FitOptions
from service import examples as ex
from service.errors import InvalidError


def _utc(moment: datetime | None) -> datetime | None:
    """Times are stored in UTC; SQLite hands them back without a zone, so add it."""
    return moment if moment is None or moment.tzinfo else moment.replace(tzinfo=UTC)


UtcDatetime = Annotated[datetime, AfterValidator(_utc)]

# Ids and versions are 32-bit integer columns: a larger number is refused (422), not sent to
# PostgreSQL (where it would fail the query: a 500). Found by tests/service/test_schemathesis.py.
MAX_DB_INT = 2**31 - 1
DbId = Annotated[int, Field(ge=1, le=MAX_DB_INT)]


class Problem(BaseModel):
    """Every error: a message naming what is wrong in the lab's terms (ids, filenames, fields)."""

    model_config = ConfigDict(json_schema_extra=ex.example(ex.PROBLEM))
    detail: str


# ---- names and free metadata of uploads, jobs, batches and trials ----------------------------
NAME_MAX_CHARS = 200  # the name columns' String(200)
METADATA_MAX_BYTES = 4096  # the object as compact UTF-8 JSON
METADATA_MAX_DEPTH = 4  # nested objects and arrays, the metadata object itself counting 1
METADATA_MAX_KEY_CHARS = 64
METADATA_MAX_STRING_CHARS = 1000


def json_depth(value: Any) -> int:
    """Nesting depth of parsed JSON (a number: 0, ``[1]``: 1), without recursion."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        item, depth = stack.pop()
        deepest = max(deepest, depth)
        if isinstance(item, dict | list):
            stack.extend((child, depth + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest


def _printable(text: str) -> str:
    """Names and metadata keys are shown in listings and folder names: no control characters
    (PostgreSQL text cannot hold NUL either)."""
    if not text.isprintable():
        raise ValueError("must not contain control characters")
    return text


def _bounded(metadata: dict[str, Any]) -> dict[str, Any]:
    """The metadata object if within the bounds above: stored as JSON and copied into every
    report.json, so a client cannot make rows or reports grow without limit."""
    if (depth := json_depth(metadata)) > METADATA_MAX_DEPTH:
        raise ValueError(f"nests {depth} levels deep; at most {METADATA_MAX_DEPTH}")
    stack: list[Any] = [metadata]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            for key in item:
                if not 1 <= len(key) <= METADATA_MAX_KEY_CHARS:
                    raise ValueError(f"key {key[:METADATA_MAX_KEY_CHARS]!r}… has {len(key)} characters; "
                                     f"keys have 1 to {METADATA_MAX_KEY_CHARS}")
                _printable(key)
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, str) and (len(item) > METADATA_MAX_STRING_CHARS or "\x00" in item):
            raise ValueError(f"a string value has {len(item)} characters; at most "
                             f"{METADATA_MAX_STRING_CHARS}, without NUL")
        elif isinstance(item, float) and not math.isfinite(item):
            raise ValueError("numbers must be finite (JSON has no NaN or Infinity)")
    size = len(json.dumps(metadata, separators=(",", ":"), ensure_ascii=False).encode())
    if size > METADATA_MAX_BYTES:
        raise ValueError(f"is {size} bytes as JSON; at most {METADATA_MAX_BYTES}")
    return metadata


Name = Annotated[str, Field(min_length=1, max_length=NAME_MAX_CHARS, examples=["walk-07"],
                            description="the lab's name for it: shown back, in report.json and in "
                                        "batch archive folder names"),
                 AfterValidator(_printable)]
Metadata = Annotated[dict[str, Any], Field(
    examples=[ex.METADATA],
    description=f"free JSON object, carried into report.json: at most {METADATA_MAX_BYTES} bytes as "
                f"JSON, {METADATA_MAX_DEPTH} levels deep, keys of 1-{METADATA_MAX_KEY_CHARS} and "
                f"strings of at most {METADATA_MAX_STRING_CHARS} characters"),
    AfterValidator(_bounded)]
_METADATA = TypeAdapter(Metadata)
_NAME = TypeAdapter(Name)


def labels_from_query(name: str | None, metadata: str | None) -> tuple[str | None, dict[str, Any] | None]:
    """``?name=`` and ``?metadata=`` (JSON text) of an upload, checked as in JSON bodies; 422
    naming the parameter."""
    try:
        checked_name = None if name is None else _NAME.validate_python(name)
    except ValidationError as exc:
        raise InvalidError(f"name: {exc.errors()[0]['msg']}") from None
    if metadata is None:
        return checked_name, None
    if len(metadata.encode()) > METADATA_MAX_BYTES:
        raise InvalidError(f"metadata: is {len(metadata.encode())} bytes; at most {METADATA_MAX_BYTES}")
    try:
        return checked_name, _METADATA.validate_json(metadata)
    except ValidationError as exc:
        raise InvalidError(f"metadata: {exc.errors()[0]['msg']}") from None


# ---- a job's options: core.options.FitOptions' fields, generated from them -----------------
def _annotation(bounds: Bounds) -> Any:
    """The pydantic type of an option of ``core.options`` with its bounds."""
    kind: Any
    if bounds.kind is bool:
        kind = bool
    elif bounds.kind is str:
        kind = (Literal[bounds.words] if bounds.words
                else Annotated[str, Field(min_length=1, max_length=bounds.max_length)])
    elif bounds.kind is tuple:
        finite = Annotated[float, Field(allow_inf_nan=False)]
        kind = Annotated[list[tuple[finite, finite]], Field(min_length=1, max_length=bounds.max_length)]
    else:
        limits = {k: v for k in ("ge", "gt", "le", "lt") if (v := getattr(bounds, k)) is not None}
        kind = Annotated[bounds.kind, Field(**limits, allow_inf_nan=False)]
        if bounds.words:
            kind = kind | Literal[bounds.words]
    return kind | None if bounds.optional else kind


def _options_model(name: str, options: type, example: dict[str, Any], doc: str,
                   **more: Any) -> type[BaseModel]:
    """A model of the options of the dataclass ``options`` (its defaults, bounds and help as
    descriptions), refusing unknown fields; ``more``: fields of other kinds, in their place."""
    bounds = bounds_of(options)
    fields: dict[str, Any] = {}
    for spec in dataclasses.fields(options):
        if spec.name in more:
            fields[spec.name] = more[spec.name]
        else:
            fields[spec.name] = (_annotation(bounds[spec.name]),
                                 Field(default=spec.default, description=bounds[spec.name].help))
    model: type[BaseModel] = create_model(
        name, __config__=ConfigDict(extra="forbid", json_schema_extra=ex.example(example)), __doc__=doc,
        __module__=__name__, **fields)
    return model


if TYPE_CHECKING:  # mypy sees BaseModel; the fields are generated (service code reads FitOptions)
    DetectorOptions = BaseModel
    _FitOptionsFields = BaseModel
else:
    DetectorOptions = _options_model(
        "DetectorOptions", DetectorParams, ex.DETECTOR, "Marker detection (``core.detect.DetectorParams``).")
    _FitOptionsFields = _options_model(
        "FitOptionsFields", FitOptions, ex.FIT_OPTIONS, "``core.options.FitOptions`` as JSON.",
        detector=(DetectorOptions, Field(default_factory=DetectorOptions,
                                         description="marker detection (as `mocap detect` previews it)")))


class JobOptions(_FitOptionsFields):
    """Everything besides model, rig and videos that decides a job's result (as ``mocap fit``):
    the fields of ``core.options.FitOptions`` (generated from it: defaults, bounds, help) and the
    service's own below. Read the fit's with :func:`fit_options`.
    """

    model_config = ConfigDict(extra="forbid", json_schema_extra=ex.example(ex.OPTIONS))
    histogram_version: DbId | None = Field(
        default=None, description="the version of the model's histogram archive to start from (the "
        "service's starting histograms); null: the latest. prior_weight applies to a version that is "
        "the uniform prior (version 1 until a job is folded in)")
    # ---- seeing the fit (service/artifacts.py, docs/SEEING_THE_FIT.md) ----
    overlay: bool = Field(default=False, description="also draw the fit over the video: "
                          "GET /v1/jobs/{id}/artifacts/overlay/... (as `mocap fit --overlay`)")
    plots: bool = Field(default=False, description="also plot angles and histograms: "
                        "GET /v1/jobs/{id}/artifacts/plots/... (as `mocap fit --plots`)")


def fit_options(options: JobOptions) -> FitOptions:
    """A job's options as ``core.options.FitOptions`` (OptionError, a ValueError: 422)."""
    data = options.model_dump(include={f.name for f in dataclasses.fields(FitOptions)})
    detector = DetectorParams(**data.pop("detector"))
    if data["root_start"] is not None:
        data["root_start"] = tuple((u, v) for u, v in data["root_start"])
    return FitOptions(**data, detector=detector)


class ModelPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.MODEL))
    id: int
    name: str = Field(description="the lab's name for it (?name= on upload), else the XML's <model name>")
    dofs: list[str]
    histogram_versions: int
    sha256: str | None = Field(description="of the XML as uploaded: identical uploads share it")
    metadata: dict[str, Any] | None
    created_at: UtcDatetime


class ExistingArchive(BaseModel):
    """An identical model (same sha256) of the same lab and its histogram archive."""

    model_config = ConfigDict(json_schema_extra=ex.example(ex.EXISTING))
    model_id: int
    histogram_versions: int
    latest_version: int = Field(description="GET /v1/models/{model_id}/histograms.xml serves it")


class ModelCreated(ModelPublic):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.MODEL_CREATED))
    existing_model_id: int | None = Field(
        description="an identical model this lab uploaded before (the one with the most histogram "
                    "versions): submit jobs with its id to go on with its archive; null: none")
    existing: ExistingArchive | None = Field(description="that model's archive; null: none")
    warnings: list[str] = Field(description="what is wrong with the model though it can be used, "
                                "e.g. DOFs its markers cannot determine in any posture and the fix; "
                                "[]: none")
    reused: bool = Field(description="true: ?reuse=true and this is that existing model, nothing "
                                     "was stored; false: a new model with a new archive (version 1)")


class RigPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.RIG_PUBLIC))
    id: int
    name: str | None
    metadata: dict[str, Any] | None
    views: list[str]
    videos: int
    created_at: UtcDatetime


class VideoPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.VIDEO))
    id: int
    filename: str
    name: str | None
    metadata: dict[str, Any] | None
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
    model_config = ConfigDict(json_schema_extra=ex.example(ex.page(ex.MODEL)))
    items: list[ModelPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class RigPage(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.page(ex.RIG_PUBLIC)))
    items: list[RigPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class VideoPage(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.page(ex.VIDEO)))
    items: list[VideoPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class JobCreate(BaseModel):
    model_config = ConfigDict(extra="forbid", json_schema_extra=ex.example(ex.JOB_CREATE))
    model_id: DbId
    rig_id: DbId
    video_ids: list[DbId] = Field(min_length=1, max_length=16)
    options: JobOptions = Field(default_factory=JobOptions)
    name: Name | None = None
    metadata: Metadata | None = None


class Trial(BaseModel):
    model_config = ConfigDict(extra="forbid", json_schema_extra=ex.example(ex.TRIALS[0]))
    video_ids: list[DbId] = Field(min_length=1, max_length=16)
    name: Name | None = None
    metadata: Metadata | None = None


class BatchCreate(BaseModel):
    model_config = ConfigDict(extra="forbid", json_schema_extra=ex.example(ex.BATCH_CREATE))
    model_id: DbId
    rig_id: DbId
    trials: list[Trial] = Field(min_length=1, max_length=1000)
    options: JobOptions = Field(default_factory=JobOptions)
    name: Name | None = None
    metadata: Metadata | None = None


class Progress(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.PROGRESS))
    images_total: int
    images_done: int
    images_over_threshold: int
    reanalyses_pending: int
    chunks_total: int
    chunks_done: int


class JobPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.JOB))
    id: int
    status: str
    model_id: int
    rig_id: int
    batch_id: int | None
    trial: int | None
    name: str | None = Field(description="the job's, or its batch trial's")
    metadata: dict[str, Any] | None
    histogram_version_id: int
    options: dict[str, Any]
    progress: Progress
    error: str | None
    created_at: UtcDatetime
    started_at: UtcDatetime | None
    fitted_at: UtcDatetime | None
    finished_at: UtcDatetime | None


class JobPage(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.page(ex.JOB)))
    items: list[JobPublic]
    next_cursor: int | None = Field(description=NEXT_CURSOR)


class BatchPublic(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.BATCH))
    id: int
    name: str | None
    metadata: dict[str, Any] | None
    status: str = Field(description="running until every job is terminal; then succeeded if all "
                                    "succeeded, else failed (or canceled if any was)")
    statuses: dict[str, int]
    progress: Progress
    jobs: list[JobPublic]


# ---- seeing the fit: detection preview (core.preview, docs/SEEING_THE_FIT.md) ----


class DetectPreviewCreate(BaseModel):
    """One frame of an uploaded video through ``core.detect``, with a rig's views of that video."""

    model_config = ConfigDict(extra="forbid", json_schema_extra=ex.example(ex.PREVIEW_CREATE))
    rig_id: DbId
    frame: int = Field(default=0, ge=0, le=MAX_DB_INT)
    video_index: int = Field(default=0, ge=0, le=255, description="which of the rig's videos this "
                             "is (its views' `video`); only those views are previewed")
    detector: DetectorOptions = Field(default_factory=DetectorOptions)


class DetectPreview(BaseModel):
    model_config = ConfigDict(json_schema_extra=ex.example(ex.PREVIEW))
    video_id: int
    rig_id: int
    frame: int
    counts: dict[str, int] = Field(description="detections per view, as core.detect (mocap fit) finds them")
    thresholds: dict[str, float] = Field(description="the grey level each view was thresholded at: the "
                                         "detector's, or what 'auto' or 'otsu' picked in this frame")
    centroids: dict[str, list[list[float]]] = Field(description="(u, v) full-frame pixels per view")
    image: str = Field(description="the frame with rois, thresholded mask and centroids: a PNG data URL")
