"""Bring a database to the newest schema: run by ``mocap serve`` on start and by the
docker-compose ``migrate`` service (``python -m service.migrate``)."""

from __future__ import annotations

import logging
from pathlib import Path

from alembic import command
from alembic.config import Config

from service.settings import get_settings

logger = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[1]


def alembic_config(url: str) -> Config:
    """Alembic's configuration for ``url``, independent of the working directory."""
    config = Config(str(ROOT / "alembic.ini"))
    config.set_main_option("script_location", str(ROOT / "migrations"))
    config.attributes["url"] = url
    return config


def upgrade(url: str | None = None) -> None:
    """``alembic upgrade head`` on ``url`` (default: the settings' database)."""
    url = url or get_settings().database_url
    logger.info("migrating %s to the newest schema", _redacted(url))
    command.upgrade(alembic_config(url), "head")


def _redacted(url: str) -> str:
    from sqlalchemy import make_url

    return make_url(url).render_as_string(hide_password=True)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO)
    upgrade()
