"""One :class:`Settings` object, read from ``MOCAP_*`` environment variables.

The defaults make ``mocap serve`` work on a fresh machine with no server
running: SQLite and kombu's filesystem broker, both under ``MOCAP_DATA_DIR``.
``MOCAP_DATABASE_URL`` and ``MOCAP_BROKER_URL`` switch to PostgreSQL and Redis.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Service settings; every field is ``MOCAP_<NAME>`` in the environment."""

    model_config = SettingsConfigDict(env_prefix="MOCAP_")

    data_dir: Path = Path("./mocap-data")
    # None: SQLite file / kombu filesystem transport under data_dir (filled in below).
    database_url: str = ""
    broker_url: str = ""
    queue: str = "mocap"
    max_upload_bytes: int = Field(default=2 * 1024**3, gt=0)
    default_chunk_size: int = Field(default=50, ge=1)
    # Limits per lab (README "Limits that protect the service"): a lab's uploads in the last
    # hour (files and bytes, from videos.created_at), its queued + running jobs, a job's frames.
    upload_files_per_hour: int = Field(default=1000, ge=1)
    upload_bytes_per_hour: int = Field(default=200 * 1024**3, ge=1)
    max_active_jobs_per_lab: int = Field(default=1000, ge=1)
    max_frames_per_job: int = Field(default=1_000_000, ge=1)
    # Slow clients (service.api.guard, service.api.server): a request's line and headers must
    # arrive within header_timeout_s; its body must send a byte at least every body_timeout_s
    # and, after the first body_timeout_s, average body_min_bytes_per_s; else 408 and closed.
    header_timeout_s: float = Field(default=10.0, gt=0)
    body_timeout_s: float = Field(default=30.0, gt=0)
    body_min_bytes_per_s: int = Field(default=16 * 1024, ge=1)
    # Open connections per API process; more are answered 503 (uvicorn's limit_concurrency).
    max_connections: int = Field(default=1000, ge=1)
    # Unknown API keys from one address in a window before it gets 429 (service.api.auth).
    auth_failures: int = Field(default=30, ge=1)
    auth_failure_window_s: float = Field(default=60.0, gt=0)
    # Cancel is cooperative: a fitting worker reads its job's status this often (seconds).
    cancel_check_s: float = Field(default=0.5, gt=0)
    # A fitting chunk writes its heartbeat at most this often (seconds); the reaper
    # (worker.reaper) re-queues a running chunk whose heartbeat is older than the timeout.
    heartbeat_s: float = Field(default=2.0, gt=0)
    heartbeat_timeout_s: float = Field(default=60.0, gt=0)
    # A chunk, plan or re-analysis queued this long while the broker's queue is empty lost
    # its message (broker flushed or restarted): the reaper sends it again.
    queued_timeout_s: float = Field(default=300.0, gt=0)
    reap_interval_s: float = Field(default=10.0, gt=0)
    # Deliveries that may start a chunk; the next one fails the job (a poison chunk).
    max_chunk_attempts: int = Field(default=3, ge=1)
    # Fault injection for the tests only: "JOB_ID:CHUNK_INDEX" makes the worker process
    # that starts that chunk exit at once (os._exit), as a poison input would crash it;
    # "JOB_ID:CHUNK_INDEX:done" exits once that chunk is counted done, before the merge.
    crash_chunk: str = ""
    # Celery: hard limit < visibility timeout, so Redis never re-delivers a chunk that is
    # still legitimately running (see worker.celery_app).
    task_soft_time_limit_s: int = Field(default=1800, gt=0)
    task_time_limit_s: int = Field(default=1900, gt=0)
    visibility_timeout_s: int = Field(default=3600, gt=0)
    # Filesystem broker poll interval (embedded mode only), seconds.
    filesystem_poll_s: float = Field(default=0.1, gt=0)

    @model_validator(mode="after")
    def _defaults_under_data_dir(self) -> Settings:
        if not self.database_url:
            self.database_url = f"sqlite:///{(self.data_dir / 'mocap.db').resolve()}"
        if not self.broker_url:
            self.broker_url = "filesystem://"
        if not self.task_soft_time_limit_s < self.task_time_limit_s < self.visibility_timeout_s:
            raise ValueError(
                "need task_soft_time_limit_s < task_time_limit_s < visibility_timeout_s, got "
                f"{self.task_soft_time_limit_s}, {self.task_time_limit_s}, {self.visibility_timeout_s}"
            )
        return self

    @property
    def storage_dir(self) -> Path:
        return self.data_dir / "storage"

    @property
    def broker_dir(self) -> Path:
        """The filesystem transport's message folder (embedded mode)."""
        return self.data_dir / "broker"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process's settings, read once from the environment."""
    return Settings()
