"""service.client imports with httpx and the standard library only: a lab installs `mocap[client]`."""

from __future__ import annotations

import json
import os
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


def test_mocap_runs_without_httpx_and_remote_says_what_to_install():
    """``mocap`` is the console script of a core-only install too: httpx is imported by the commands."""
    blocked = "import sys; sys.modules['httpx'] = None; sys.argv = ['mocap', *sys.argv[1:]]; "
    run = blocked + "from service.cli import run; run()"
    listed = subprocess.run([sys.executable, "-c", run, "--help"], capture_output=True, text=True)
    assert listed.returncode == 0 and "remote" in listed.stdout, listed.stderr
    remote = subprocess.run([sys.executable, "-c", run, "remote", "status", "job", "1"],
                            capture_output=True, text=True, env={**os.environ, "MOCAP_API_KEY": "k"})
    assert remote.returncode == 2
    assert remote.stderr == ("mocap: error: mocap remote needs httpx: "
                             "python3 -m pip install 'mocap[client]'\n")
