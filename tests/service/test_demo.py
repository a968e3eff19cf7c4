"""`mocap demo --service`: the quick start's demo through the embedded service, as a user runs it."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest


@pytest.mark.slow  # starts the embedded service, its workers and a fit: ~15 s
def test_the_service_demo_fits_the_locust_clip_over_http(tmp_path):
    """Embedded default (SQLite, filesystem broker, worker processes): nothing to start first."""
    done = subprocess.run(
        [sys.executable, "-m", "service.cli", "demo", "--service", "--samples", "30", "--workers", "1"],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.search(r"job 1 succeeded in [\d.]+ s: 30 images, 0 over threshold", done.stdout)
    line = done.stdout.split("(degrees):")[1].splitlines()[0]
    rmse = [float(v) for v in re.findall(r"\w+ (\d+\.\d+)", line)]
    assert len(rmse) == 5 and max(rmse) < 0.5, done.stdout
    assert list(tmp_path.iterdir()) == []  # everything lived in a temporary directory
