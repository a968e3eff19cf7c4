"""``mocap admin`` (issue 12, item 9): every command says which database it uses, and keys can be
listed, revoked and rotated. Run on a SQLite database in a temporary folder; the HTTP effect of
each command on PostgreSQL is in test_http_hardening.py."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from sqlalchemy.orm import Session

from service.db import make_engine
from service.labs import lab_for_key


def _admin(data: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("MOCAP_DATABASE_URL", "MOCAP_BROKER_URL")}
    env["MOCAP_DATA_DIR"] = str(data)
    return subprocess.run([sys.executable, "-m", "service.cli", "admin", *args], env=env,
                          capture_output=True, text=True, cwd=data.parent)


def _opens(data: Path, key: str) -> int | None:
    """The id of the lab ``key`` opens, None if none."""
    engine = make_engine(f"sqlite:///{data / 'mocap.db'}")
    try:
        with Session(engine) as session:
            lab = lab_for_key(session, key)
            return None if lab is None else lab.id
    finally:
        engine.dispose()


@pytest.mark.slow  # 5 processes: ~5 s, 15 s on a busy machine
def test_create_list_revoke_and_rotate(tmp_path):
    data = tmp_path / "lab-data"
    database = f"database: sqlite:///{data.resolve() / 'mocap.db'}"
    first = _admin(data, "create-lab", "Dürr lab")
    assert first.returncode == 0, first.stderr
    lines = first.stdout.splitlines()
    assert lines[0] == database + " (new: created now; set MOCAP_DATABASE_URL or MOCAP_DATA_DIR if you " \
                                  "meant another)"
    key = lines[-1]
    second = _admin(data, "create-lab", "Other lab")
    assert second.stdout.splitlines()[0] == database  # no longer new
    assert _opens(data, key) == 1

    revoked = _admin(data, "revoke-key", "1")
    assert revoked.returncode == 0 and "revoked the API key of lab 1 (Dürr lab)" in revoked.stdout
    assert _opens(data, key) is None
    listed = _admin(data, "list-labs").stdout.splitlines()
    assert listed[:2] == [database, "2 lab(s)"]
    assert listed[2].split()[:2] == ["1", "revoked"] and listed[2].endswith("Dürr lab")
    assert listed[3].split()[:2] == ["2", "active"] and listed[3].endswith("Other lab")

    rotated = _admin(data, "rotate-key", "1")
    assert rotated.returncode == 0
    new_key = rotated.stdout.splitlines()[-1]
    assert new_key != key and _opens(data, new_key) == 1 and _opens(data, key) is None
    assert _opens(data, second.stdout.splitlines()[-1]) == 2  # the other lab untouched


def test_an_unknown_lab_or_an_unusable_database_is_exit_2_with_one_line(tmp_path):
    data = tmp_path / "lab-data"
    done = _admin(data, "rotate-key", "7")
    assert done.returncode == 2
    assert done.stderr == "mocap: error: there is no lab 7 in this database (mocap admin list-labs)\n"
    env = {**os.environ, "MOCAP_DATABASE_URL": "postgresql+psycopg://mocap:secret@127.0.0.1:1/nowhere"}
    done = subprocess.run([sys.executable, "-m", "service.cli", "admin", "list-labs"], env=env,
                          capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert done.stderr.startswith("mocap: error: cannot use the database "
                                  "postgresql+psycopg://mocap@127.0.0.1:1/nowhere: ")
    assert "secret" not in done.stdout + done.stderr
