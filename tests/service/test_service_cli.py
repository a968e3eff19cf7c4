"""The console script: core's commands work without the service's dependencies loaded."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

SERVICE_DEPENDENCIES = ("fastapi", "sqlalchemy", "celery", "alembic", "psycopg", "pydantic_settings")


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", f"{code}; import sys; print(' '.join(sys.modules))"],
                         capture_output=True, text=True, check=True).stdout
    return {name.split(".")[0] for name in out.split()}


def test_the_console_script_loads_no_service_dependency_until_a_service_command_runs():
    loaded = _modules_after("import service.cli")
    assert not loaded & set(SERVICE_DEPENDENCIES)


def test_core_never_imports_the_service():
    loaded = _modules_after("import core, cli.app, core.pipeline")
    assert "service" not in loaded and "worker" not in loaded


def test_the_api_imports_no_worker_module():
    loaded = _modules_after("import service.api.app")
    assert "service" in loaded and "worker" not in loaded


def test_only_the_console_script_in_service_imports_worker():
    """worker depends on service (persistence, the queue), never the reverse: service.cli, the
    composition root, is the one module of service that may import worker."""
    service = Path(__file__).resolve().parents[2] / "service"
    importers = set()
    for path in service.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n == "worker" or n.startswith("worker.") for n in names):
                importers.add(path.relative_to(service.parent).as_posix())
    assert importers == {"service/cli.py"}


def test_mocap_lists_core_and_service_commands():
    out = subprocess.run([sys.executable, "-m", "service.cli", "--help"], capture_output=True, text=True,
                         check=True).stdout
    for command in ("fit", "synth", "demo", "serve", "worker", "admin"):
        assert command in out
