"""``mocap``'s service commands (``serve``, ``worker``, ``reap``, ``admin create-lab``,
``list-labs``, ``revoke-key``, ``rotate-key``,
``demo --service``, ``remote …``) added to the CLI of ``cli.app`` (fit, synth, demo …).

This is the console script: it registers the commands below on ``cli.app.app``
and runs it. Service code is imported inside the commands, so ``mocap fit``,
``synth`` and ``demo`` work where the service's dependencies are not installed;
neither ``core`` nor ``cli`` imports this package.

It is the composition root, the one module of ``service`` that may import ``worker``
(``serve`` and ``reap`` run the reaper, ``worker.reaper``): ``worker`` depends on
``service`` (database, models, settings, storage, ``service.broker``'s queue), never the
reverse; no module of the packages imports this one, so the dependency stays one-way
(``tests/service/test_service_cli.py`` checks it). ``mocap worker`` names the worker's
Celery app only as a command line (``celery -A worker.celery_app``).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Annotated

import typer

from cli.app import app, user_errors
from cli.app import demo as local_demo
from cli.app import run as run_core
from service.remote import remote

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

admin = typer.Typer(no_args_is_help=True, help="Administer labs.")
app.add_typer(admin, name="admin")
app.add_typer(remote, name="remote")  # imports httpx only when a `remote` command runs
# `demo` gains --service here; core's own command (no flag) is replaced, not duplicated.
app.registered_commands[:] = [c for c in app.registered_commands if c.callback is not local_demo]


def run() -> None:
    """Console entry point (``mocap``)."""
    run_core()


def _celery_command(concurrency: int) -> list[str]:
    return [sys.executable, "-m", "celery", "-A", "worker.celery_app", "worker",
            f"--concurrency={concurrency}", "--loglevel=INFO", "--without-mingle", "--without-gossip"]


def _start_workers(concurrency: int, nice: int) -> subprocess.Popen[bytes]:
    """``celery worker`` with ``concurrency`` processes at CPU priority ``nice`` (0 normal, 19 lowest)."""
    return subprocess.Popen(_celery_command(concurrency),
                            preexec_fn=(lambda: os.nice(nice)) if nice else None)


@app.command()
def serve(
    port: Annotated[int, typer.Option(min=1, max=65535, help="HTTP port of the API")] = 8000,
    host: Annotated[str, typer.Option(help="address to listen on")] = "127.0.0.1",
    workers: Annotated[int, typer.Option(min=0, max=256, help="Celery worker processes (0: none)")] = 1,
    nice: Annotated[int, typer.Option(min=0, max=19, help="CPU priority of the workers: fitting "
                                      "yields to the API on a shared machine")] = 10,
) -> None:
    """Run the API and worker processes: SQLite and a filesystem broker unless MOCAP_* say otherwise."""
    from service.api.server import serve as serve_api
    from service.migrate import upgrade
    from service.settings import get_settings
    from worker.reaper import start_reaper

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings = get_settings()
    with user_errors():
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        upgrade()
    pool = _start_workers(workers, nice) if workers else None
    start_reaper()  # also with --workers 0: workers elsewhere may all be down
    print(f"mocap: API on http://{host}:{port}/v1 (docs at /docs), {workers} worker process(es), "
          f"data in {settings.data_dir.resolve()}", flush=True)
    # uvicorn re-raises SIGTERM once it has shut down; as SystemExit, the workers are stopped below.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        serve_api(host, port)
    finally:
        if pool is not None:
            pool.send_signal(signal.SIGTERM)  # warm shutdown: running tasks finish or are re-queued
            pool.wait(timeout=60)


@app.command()
def worker(
    concurrency: Annotated[int, typer.Option(min=1, max=256, help="processes fitting chunks")] = (
        os.cpu_count() or 1),
    nice: Annotated[int, typer.Option(min=0, max=19, help="CPU priority (0 normal, 19 lowest)")] = 0,
) -> None:
    """Run a Celery worker alone (another machine: set MOCAP_DATABASE_URL and MOCAP_BROKER_URL).

    The process becomes the Celery worker (exec), so SIGTERM from a supervisor or
    ``docker stop`` reaches Celery itself: a warm shutdown, never an orphaned pool.
    """
    if nice:
        os.nice(nice)
    command = _celery_command(concurrency)
    os.execv(command[0], command)


@app.command()
def demo(
    samples: Annotated[int, typer.Option(min=1, max=5000, help="images to render and fit")] = 200,
    seed: Annotated[int, typer.Option(help="seed of the movement, the rendering and the fit")] = 2004,
    service: Annotated[bool, typer.Option(
        "--service", help="through the embedded service: mocap serve (SQLite, filesystem broker, "
        "worker processes) in a temporary directory, driven over HTTP")] = False,
    workers: Annotated[int, typer.Option(min=1, max=16, help="worker processes with --service")] = 2,
) -> None:
    """Render the locust hind-leg example, fit it and print the accuracy against the truth."""
    if not service:
        local_demo(samples=samples, seed=seed)
        return
    try:
        from service.client import ClientError
        from service.demo import run_demo
    except ModuleNotFoundError as exc:
        typer.echo(f"mocap: error: --service needs the service's packages ({exc.name} is missing): "
                   "python3 -m pip install -e '.[service]'", err=True)
        raise typer.Exit(2) from None
    try:
        run_demo(samples, seed, workers)
    except (RuntimeError, OSError, subprocess.CalledProcessError, ClientError) as exc:
        typer.echo(f"mocap: error: {exc}", err=True)
        raise typer.Exit(1) from None


@app.command()
def reap() -> None:
    """One reaper pass (for cron): send again stale chunks and work whose message was lost."""
    from worker.reaper import reap as reap_once

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    with user_errors():
        reaped = reap_once()
    print(f"stale chunks {len(reaped.stale_chunks)}, lost chunks {len(reaped.lost_chunks)}, "
          f"lost plans {len(reaped.lost_plans)}, lost re-analyses {reaped.lost_reanalyses}, "
          f"resumed jobs {len(reaped.resumed)}")


@admin.command("create-lab")
def create_lab(name: Annotated[str, typer.Argument(help="the lab's name")]) -> None:
    """Create a lab and print its API key (last line; shown only this once)."""
    from service.labs import create_lab as create

    with _admin_session() as session:
        lab, key = create(session, name)
        lab_id = lab.id
    print(f"created lab {lab_id} ({name}); its API key (store it, it is shown only once):")
    print(key)


@admin.command("list-labs")
def list_labs() -> None:
    """List the labs: id, whether their key is active or revoked, creation time, name."""
    from service.labs import all_labs

    with _admin_session() as session:
        labs = all_labs(session)
        print(f"{len(labs)} lab(s)")
        for lab in labs:
            state = "active " if lab.key_hash else "revoked"
            print(f"{lab.id:>6}  {state}  {lab.created_at:%Y-%m-%d %H:%M}  {lab.name}")


@admin.command("revoke-key")
def revoke_key(lab_id: Annotated[int, typer.Argument(help="the lab's id (mocap admin list-labs)")]) -> None:
    """Revoke a lab's API key: its requests get 401 until `rotate-key` gives it a new one."""
    from service.labs import revoke_key as revoke

    with _admin_session() as session:
        lab = revoke(session, lab_id)
        print(f"revoked the API key of lab {lab.id} ({lab.name})")


@admin.command("rotate-key")
def rotate_key(lab_id: Annotated[int, typer.Argument(help="the lab's id (mocap admin list-labs)")]) -> None:
    """Give a lab a new API key (last line; shown only this once); the old one stops working."""
    from service.labs import rotate_key as rotate

    with _admin_session() as session:
        lab, key = rotate(session, lab_id)
        print(f"new API key of lab {lab.id} ({lab.name}); the old one no longer works (store it, it "
              "is shown only once):")
    print(key)


@contextmanager
def _admin_session() -> Iterator[Session]:
    """A committed session on the settings' database, migrated first, after printing which
    database it is (run from another folder, the default SQLite file is another database).
    A database that cannot be used is exit code 2 with one line."""
    from sqlalchemy import inspect, make_url
    from sqlalchemy.exc import SQLAlchemyError

    from service.db import get_engine, session_scope
    from service.migrate import upgrade
    from service.settings import get_settings

    shown = make_url(get_settings().database_url)._replace(password=None).render_as_string(False)
    with user_errors():
        try:
            fresh = "alembic_version" not in inspect(get_engine()).get_table_names()
            print(f"database: {shown}" + (" (new: created now; set MOCAP_DATABASE_URL or "
                                          "MOCAP_DATA_DIR if you meant another)" if fresh else ""))
            upgrade()
            with session_scope() as session:
                yield session
        except SQLAlchemyError as exc:
            problem = str(getattr(exc, "orig", None) or exc).splitlines()[0]
            raise ValueError(f"cannot use the database {shown}: {problem}") from None


if __name__ == "__main__":
    run()
