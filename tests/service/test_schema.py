"""``alembic upgrade head`` on an empty database gives exactly the models' schema."""

from __future__ import annotations

import uuid

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from conftest import PG_ADMIN_URL, require_servers
from sqlalchemy import inspect, text

from service.db import make_engine
from service.migrate import upgrade
from service.models import Base


def _diff(url: str) -> tuple[set[str], list]:
    upgrade(url)
    engine = make_engine(url)
    try:
        with engine.connect() as conn:
            tables = set(inspect(conn).get_table_names())
            return tables, compare_metadata(MigrationContext.configure(conn), Base.metadata)
    finally:
        engine.dispose()


def test_sqlite_migrations_give_the_models_schema(tmp_path):
    tables, diff = _diff(f"sqlite:///{tmp_path / 'empty.db'}")
    assert tables == set(Base.metadata.tables) | {"alembic_version"}
    assert diff == []


@pytest.mark.service
def test_postgresql_migrations_give_the_models_schema():
    require_servers()
    schema = f"mocap_schema_{uuid.uuid4().hex[:10]}"
    admin = make_engine(PG_ADMIN_URL)
    with admin.begin() as conn:
        conn.execute(text(f'CREATE SCHEMA "{schema}"'))
    try:
        tables, diff = _diff(f"{PG_ADMIN_URL}?options=-csearch_path%3D{schema}")
        assert tables == set(Base.metadata.tables) | {"alembic_version"}
        assert diff == []
    finally:
        with admin.begin() as conn:
            conn.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))
        admin.dispose()


def test_upgrade_twice_changes_nothing(tmp_path):
    url = f"sqlite:///{tmp_path / 'twice.db'}"
    upgrade(url)
    _, diff = _diff(url)
    assert diff == []
