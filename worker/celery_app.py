"""The worker's Celery app: ``service.broker``'s app (settings and why: there) with the tasks.

``worker.tasks`` registers the tasks under ``service.broker``'s names and ``worker.reaper`` its
signals; both are imported when ``celery -A worker.celery_app worker`` starts.

``worker_init``: the main process compiles the fitting kernels (``core.warmup``) before the
prefork pool forks, so the pool's processes inherit them: a fresh machine compiles once,
not once per worker process, and says so in the log.
"""

from __future__ import annotations

import logging
from typing import Any

from celery import signals

from service.broker import celery_app

app = celery_app()
app.conf.include = ["worker.tasks", "worker.reaper"]


@signals.worker_init.connect  # type: ignore[untyped-decorator]  # Celery has no types
def compile_before_forking(**_: Any) -> None:
    """Compile (or load) the kernels in the worker's main process, before its pool forks."""
    from core.warmup import compile_kernels_saying_so  # flower imports this module too: not there

    compile_kernels_saying_so(logging.getLogger("mocap.worker").warning)
