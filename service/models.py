"""SQLAlchemy 2 models: the database is the source of truth for jobs, chunks and results.

Counts a status poll needs (images done, over threshold, re-analyses pending,
chunks done) live on the job row and are updated atomically by the workers, so
``GET /v1/jobs/{id}`` is one indexed primary-key read, never a scan of images.
Status values are plain strings (see :class:`JobStatus`) so the schema is the
same on SQLite and PostgreSQL.
"""

from __future__ import annotations

import enum
from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    # Named constraints: Alembic can alter them later, SQLite's batch mode included.
    metadata = MetaData(naming_convention={
        "ix": "ix_%(column_0_label)s", "uq": "uq_%(table_name)s_%(column_0_N_name)s",
        "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s", "pk": "pk_%(table_name)s",
    })
    type_annotation_map: ClassVar[dict[Any, Any]] = {dict[str, Any]: JSON, datetime: DateTime(timezone=True)}


class JobStatus(enum.StrEnum):
    QUEUED = "queued"
    RUNNING = "running"
    REANALYSING = "reanalysing"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELED = "canceled"


TERMINAL = frozenset({JobStatus.SUCCEEDED, JobStatus.FAILED, JobStatus.CANCELED})


class ChunkStatus(enum.StrEnum):
    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELED = "canceled"


class Lab(Base):
    """A tenant: every other row belongs to one lab, reached through its API key."""

    __tablename__ = "labs"
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    key_hash: Mapped[str | None] = mapped_column(String(64), unique=True)  # sha256 hex; None: revoked
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Model(Base):
    """A kinematic model (FORMATS §1), its XML as uploaded; ``sha256`` of those bytes finds an
    identical model of the lab (and its histogram archive) when one is uploaded again."""

    __tablename__ = "models"
    __table_args__ = (Index("ix_models_lab_id_sha256", "lab_id", "sha256"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    lab_id: Mapped[int] = mapped_column(ForeignKey("labs.id"), index=True)
    name: Mapped[str] = mapped_column(String(200))  # the lab's, or the XML's <model name>
    xml: Mapped[str] = mapped_column(Text)
    sha256: Mapped[str | None] = mapped_column(String(64))
    meta: Mapped[dict[str, Any] | None] = mapped_column("metadata", JSON)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class HistogramVersion(Base):
    """One version of a model's histogram archive; the exact state (counts, probabilities)
    lives in storage as ``.npz``, XML is rendered from it on download."""

    __tablename__ = "histogram_versions"
    __table_args__ = (UniqueConstraint("model_id", "version"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    model_id: Mapped[int] = mapped_column(ForeignKey("models.id"))
    version: Mapped[int] = mapped_column(Integer)
    storage_key: Mapped[str] = mapped_column(String(200))
    # The job folded in (None: the uniform prior). No foreign key: jobs reference their
    # starting version, and a cycle of foreign keys cannot be created in one migration.
    job_id: Mapped[int | None] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class RigRow(Base):
    """A camera rig (FORMATS §2), its JSON as uploaded."""

    __tablename__ = "rigs"
    id: Mapped[int] = mapped_column(primary_key=True)
    lab_id: Mapped[int] = mapped_column(ForeignKey("labs.id"), index=True)
    spec: Mapped[dict[str, Any]] = mapped_column(JSON)
    name: Mapped[str | None] = mapped_column(String(200))
    meta: Mapped[dict[str, Any] | None] = mapped_column("metadata", JSON)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Video(Base):
    """An uploaded video, registered only once fully stored and probed."""

    __tablename__ = "videos"
    id: Mapped[int] = mapped_column(primary_key=True)
    lab_id: Mapped[int] = mapped_column(ForeignKey("labs.id"), index=True)
    storage_key: Mapped[str] = mapped_column(String(200))
    filename: Mapped[str] = mapped_column(String(255))  # shown back only, never a path
    frames: Mapped[int] = mapped_column(Integer)  # that decode
    # What the container announces (None: uploaded before this was recorded); more than
    # ``frames`` for a truncated file.
    announced_frames: Mapped[int | None] = mapped_column(Integer)
    fps: Mapped[float] = mapped_column(Float)
    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    size_bytes: Mapped[int] = mapped_column(BigInteger)  # 2 GiB and more
    sha256: Mapped[str] = mapped_column(String(64))
    name: Mapped[str | None] = mapped_column(String(200))
    meta: Mapped[dict[str, Any] | None] = mapped_column("metadata", JSON)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Batch(Base):
    """Trials submitted together, one job each, sharing model, rig and options."""

    __tablename__ = "batches"
    id: Mapped[int] = mapped_column(primary_key=True)
    lab_id: Mapped[int] = mapped_column(ForeignKey("labs.id"), index=True)
    name: Mapped[str | None] = mapped_column(String(200))
    meta: Mapped[dict[str, Any] | None] = mapped_column("metadata", JSON)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Job(Base):
    """One fitting job; its counters make a status poll a single row read."""

    __tablename__ = "jobs"
    __table_args__ = (Index("ix_jobs_lab_status_id", "lab_id", "status", "id"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    lab_id: Mapped[int] = mapped_column(ForeignKey("labs.id"), index=True)
    batch_id: Mapped[int | None] = mapped_column(ForeignKey("batches.id"), index=True)
    trial: Mapped[int | None] = mapped_column(Integer)  # index in its batch
    name: Mapped[str | None] = mapped_column(String(200))  # the job's, or its trial's
    meta: Mapped[dict[str, Any] | None] = mapped_column("metadata", JSON)
    # Indexed: deleting an upload looks up the jobs that name it.
    model_id: Mapped[int] = mapped_column(ForeignKey("models.id"), index=True)
    rig_id: Mapped[int] = mapped_column(ForeignKey("rigs.id"), index=True)
    histogram_version_id: Mapped[int] = mapped_column(ForeignKey("histogram_versions.id"))
    options: Mapped[dict[str, Any]] = mapped_column(JSON)
    status: Mapped[str] = mapped_column(String(16), default=JobStatus.QUEUED)
    error: Mapped[str | None] = mapped_column(Text)
    images_total: Mapped[int] = mapped_column(Integer, default=0)
    images_done: Mapped[int] = mapped_column(Integer, default=0)
    images_over_threshold: Mapped[int] = mapped_column(Integer, default=0)
    reanalyses_pending: Mapped[int] = mapped_column(Integer, default=0)
    chunks_total: Mapped[int] = mapped_column(Integer, default=0)
    chunks_done: Mapped[int] = mapped_column(Integer, default=0)
    typical_objective: Mapped[float | None] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column()
    fitted_at: Mapped[datetime | None] = mapped_column()  # every chunk done
    # Last sign of life of a queued or re-analysing job (re-analysis stored, reaper re-sent
    # its messages): the reaper's clock for lost plan and re-analysis messages.
    progress_at: Mapped[datetime | None] = mapped_column()
    finished_at: Mapped[datetime | None] = mapped_column()


class JobVideo(Base):
    """The job's videos, one per camera in the rig's ``video`` index order."""

    __tablename__ = "job_videos"
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id"), primary_key=True)
    position: Mapped[int] = mapped_column(Integer, primary_key=True)
    video_id: Mapped[int] = mapped_column(ForeignKey("videos.id"), index=True)


class Chunk(Base):
    """A frame range fitted by one task; ``attempts`` counts deliveries that started it."""

    __tablename__ = "chunks"
    __table_args__ = (UniqueConstraint("job_id", "index"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id"))
    index: Mapped[int] = mapped_column(Integer)
    first: Mapped[int] = mapped_column(Integer)
    last: Mapped[int] = mapped_column(Integer)  # exclusive
    status: Mapped[str] = mapped_column(String(16), default=ChunkStatus.QUEUED)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    queued_at: Mapped[datetime | None] = mapped_column()  # last sent to the broker
    heartbeat_at: Mapped[datetime | None] = mapped_column()
    worker: Mapped[str | None] = mapped_column(String(255))
    error: Mapped[str | None] = mapped_column(Text)
    observed_key: Mapped[str | None] = mapped_column(String(200))  # exact histogram counts


class ImageResult(Base):
    """The best fit of one image so far (``ImageFit.to_record()``)."""

    __tablename__ = "image_results"
    __table_args__ = (UniqueConstraint("job_id", "sample"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id"))
    sample: Mapped[int] = mapped_column(Integer)
    attempts: Mapped[int] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(16))
    error_px: Mapped[float | None] = mapped_column(Float)
    record: Mapped[dict[str, Any]] = mapped_column(JSON)


class Attempt(Base):
    """Every attempt on an image: the best fit after that attempt (1 = the chunk's fit)."""

    __tablename__ = "attempts"
    __table_args__ = (UniqueConstraint("job_id", "sample", "attempt"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id"))
    sample: Mapped[int] = mapped_column(Integer)
    attempt: Mapped[int] = mapped_column(Integer)
    error_px: Mapped[float | None] = mapped_column(Float)
    objective: Mapped[float | None] = mapped_column(Float)
    worker: Mapped[str | None] = mapped_column(String(255))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
