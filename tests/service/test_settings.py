"""Settings: defaults that need no server, MOCAP_* overrides, consistent Celery limits."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from service.settings import Settings


def test_defaults_put_sqlite_and_the_filesystem_broker_under_the_data_dir(monkeypatch, tmp_path):
    for name in ("MOCAP_DATABASE_URL", "MOCAP_BROKER_URL", "MOCAP_DATA_DIR"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    settings = Settings()
    assert settings.data_dir == Path("mocap-data")
    assert settings.database_url == f"sqlite:///{tmp_path.resolve() / 'mocap-data' / 'mocap.db'}"
    assert settings.broker_url == "filesystem://"


def test_environment_overrides(monkeypatch):
    monkeypatch.setenv("MOCAP_DATABASE_URL", "postgresql+psycopg://u@db/mocap")
    monkeypatch.setenv("MOCAP_BROKER_URL", "redis://redis:6379/0")
    monkeypatch.setenv("MOCAP_MAX_UPLOAD_BYTES", "1000")
    settings = Settings()
    assert (settings.database_url, settings.broker_url, settings.max_upload_bytes) == (
        "postgresql+psycopg://u@db/mocap", "redis://redis:6379/0", 1000)


def test_time_limits_must_stay_below_the_visibility_timeout(monkeypatch):
    monkeypatch.setenv("MOCAP_VISIBILITY_TIMEOUT_S", "1000")
    with pytest.raises(ValidationError, match="visibility_timeout_s"):
        Settings()
