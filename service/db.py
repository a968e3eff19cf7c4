"""Engine and sessions: one engine per process, SQLite tuned for concurrent workers.

SQLite (embedded mode) gets WAL journaling, so the API reads while a worker
writes, and a busy timeout, so concurrent writers wait instead of failing
with "database is locked". Transactions start with ``BEGIN IMMEDIATE``: a
deferred transaction that reads and then writes cannot wait for another
writer (SQLite returns "locked" at once rather than risk a deadlock), and
the workers' transactions all read then write. Read-only sessions (the API's
GET requests, :func:`read_session_factory`) begin deferred: in WAL mode a
reader never waits for the writer, so a status poll is not queued behind a
worker's transaction.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Any, cast

from sqlalchemy import CursorResult, Engine, Update, create_engine, event, make_url
from sqlalchemy.engine import Connection
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import ConnectionPoolEntry

from service.settings import get_settings

SQLITE_BUSY_TIMEOUT_MS = 30_000
READ_ONLY = "mocap_read_only"  # execution option of read-only sessions


def make_engine(url: str) -> Engine:
    """An engine for ``url``; SQLite connections in WAL mode with a busy timeout."""
    if not url.startswith("sqlite"):
        return create_engine(url, pool_pre_ping=True)
    database = make_url(url).database
    if database and database != ":memory:":
        Path(database).parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(url, connect_args={"check_same_thread": False,
                                              "timeout": SQLITE_BUSY_TIMEOUT_MS / 1000})

    @event.listens_for(engine, "connect")
    def _pragmas(dbapi_connection: sqlite3.Connection, _record: ConnectionPoolEntry) -> None:
        dbapi_connection.isolation_level = None  # we emit BEGIN ourselves, below
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.close()

    @event.listens_for(engine, "begin")
    def _begin(connection: Connection) -> None:
        read_only = connection.get_execution_options().get(READ_ONLY, False)
        connection.exec_driver_sql("BEGIN DEFERRED" if read_only else "BEGIN IMMEDIATE")

    return engine


@lru_cache(maxsize=1)
def get_engine() -> Engine:
    """The process's engine, from the settings."""
    return make_engine(get_settings().database_url)


@lru_cache(maxsize=1)
def session_factory() -> sessionmaker[Session]:
    return sessionmaker(get_engine(), expire_on_commit=False)


@lru_cache(maxsize=1)
def read_session_factory() -> sessionmaker[Session]:
    """Sessions for requests that only read (on SQLite: deferred transactions)."""
    return sessionmaker(get_engine().execution_options(**{READ_ONLY: True}), expire_on_commit=False)


@contextmanager
def session_scope() -> Iterator[Session]:
    """A session committed on success and rolled back on error (workers, CLI)."""
    with session_factory()() as session:
        try:
            yield session
            session.commit()
        except BaseException:
            session.rollback()
            raise


def rows_changed(session: Session, statement: Update) -> int:
    """Rows a guarded UPDATE changed: 0 means another transaction (a second delivery, a racing
    reaper, a cancel) changed the row first, so the caller does nothing."""
    # An UPDATE's result is a CursorResult, which has rowcount; Session.execute is typed as Result.
    return cast(CursorResult[Any], session.execute(statement)).rowcount
