"""service.client imports with httpx and the standard library only: a lab installs `mocap[client]`."""

from __future__ import annotations

import json
import subprocess
import sys

SERVER_PACKAGES = ("fastapi", "starlette", "sqlalchemy", "alembic", "celery", "kombu", "pydantic",
                   "pydantic_settings", "numpy", "numba", "cv2", "core", "worker")


def test_the_client_imports_none_of_the_servers_packages():
    probe = ("import json, sys; import service.client; "
             "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    imported = set(json.loads(done.stdout))
    assert "httpx" in imported
    assert imported.isdisjoint(SERVER_PACKAGES), sorted(imported & set(SERVER_PACKAGES))
