"""The console script: core's commands work without the service's dependencies loaded."""

from __future__ import annotations

import subprocess
import sys

SERVICE_DEPENDENCIES = ("fastapi", "sqlalchemy", "celery", "alembic", "psycopg", "pydantic_settings")


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", f"{code}; import sys; print(' '.join(sys.modules))"],
                         capture_output=True, text=True, check=True).stdout
    return {name.split(".")[0] for name in out.split()}


def test_the_console_script_loads_no_service_dependency_until_a_service_command_runs():
    loaded = _modules_after("import service.cli")
    assert not loaded & set(SERVICE_DEPENDENCIES)


def test_core_never_imports_the_service():
    loaded = _modules_after("import core, core.cli, core.pipeline")
    assert "service" not in loaded and "worker" not in loaded


def test_mocap_lists_core_and_service_commands():
    out = subprocess.run([sys.executable, "-m", "service.cli", "--help"], capture_output=True, text=True,
                         check=True).stdout
    for command in ("fit", "synth", "demo", "serve", "worker", "admin"):
        assert command in out
