"""The fitting kernels compiled once, before any test, the way ``mocap fit`` and the workers do.

Without this the first test that fits compiles every kernel in its own process (about two
minutes of one core on a 2-core machine); ``core.warmup`` compiles them on both cores into
numba's cache. Under pytest-xdist only the controller compiles, and its workers load the cache.
"""

from __future__ import annotations

import pytest

from core.warmup import compile_kernels_saying_so


def pytest_sessionstart(session: pytest.Session) -> None:
    """Before xdist starts its workers (its own hook runs last)."""
    config = session.config
    if hasattr(config, "workerinput") or config.option.collectonly:
        return  # an xdist worker: the controller has filled the cache
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    compile_kernels_saying_so(lambda line: reporter.write_line(line) if reporter else None)
