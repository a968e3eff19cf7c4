"""SQLite as the embedded database: WAL, busy timeout, writers take the lock up front, readers don't."""

from __future__ import annotations

from sqlalchemy import event, text

from service.db import READ_ONLY, make_engine


def test_sqlite_sessions_begin_immediate_and_read_only_ones_deferred(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'nested' / 'mocap.db'}")  # parent folder created
    begins: list[str] = []
    event.listen(engine, "before_cursor_execute",
                 lambda _c, _cur, statement, *_: begins.append(statement) if "BEGIN" in statement else None)
    with engine.begin() as conn:
        assert conn.execute(text("PRAGMA journal_mode")).scalar_one() == "wal"
        assert conn.execute(text("PRAGMA busy_timeout")).scalar_one() == 30_000
    with engine.execution_options(**{READ_ONLY: True}).begin() as conn:
        conn.execute(text("SELECT 1"))
    assert begins == ["BEGIN IMMEDIATE", "BEGIN DEFERRED"]
    engine.dispose()


def test_a_reader_is_not_blocked_by_an_open_write_transaction(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'mocap.db'}")
    with engine.begin() as conn:
        conn.execute(text("CREATE TABLE t (x INTEGER)"))
    with engine.begin() as writer:
        writer.execute(text("INSERT INTO t VALUES (1)"))  # holds the write lock, uncommitted
        with engine.execution_options(**{READ_ONLY: True}).connect() as reader:
            assert reader.execute(text("SELECT count(*) FROM t")).scalar_one() == 0  # at once
    engine.dispose()
