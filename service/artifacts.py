"""A job's optional artifacts: overlays (``core.overlay``) and plots (``core.plots``).

Rendered by the worker that finishes a job whose options ask for them, after the
results and before the job is marked succeeded, with the same functions as
``mocap fit --overlay --plots``; stored under ``jobs/<id>/`` with the names those
write in a results directory (``overlay/…``, ``plots/…``), listed in
``jobs/<id>/artifacts.json`` (:data:`INDEX`), which the API reads to serve and
archive them.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
import tempfile
from collections.abc import Callable
from functools import partial
from pathlib import Path

from core.histogram import Histograms
from core.overlay import OVERLAY_DIR, overlay_job
from core.pipeline import FitJob
from core.plots import PLOTS_DIR, write_plots
from core.results import read_angles_csv, write_angles_csv
from core.sequence import SequenceResult
from service.storage import Storage

__all__ = ["INDEX", "MEDIA_TYPES", "NAME", "listed", "render"]

logger = logging.getLogger(__name__)

INDEX = "artifacts.json"
# Every name an artifact can have (what core.overlay and core.plots write): the API serves
# nothing else under a job's artifacts/.
NAME = re.compile(
    rf"^({OVERLAY_DIR}/(video\d{{1,3}}\.avi|contact_sheet\.png|overlay\.json|images/sample_\d{{6,}}\.png)"
    rf"|{PLOTS_DIR}/(angles|histograms)\.(png|svg))$"
)
MEDIA_TYPES = {".avi": "video/x-msvideo", ".png": "image/png", ".json": "application/json",
               ".svg": "image/svg+xml"}


def render(storage: Storage, job_id: int, fit: FitJob, start: Histograms, result: SequenceResult, *,
           overlay: bool, plots: bool) -> dict[str, object]:
    """Draw the job's overlay and/or plots and store them; return what :data:`INDEX` holds.

    A drawing that fails is logged and named in the index's ``error`` (the other is still
    drawn): the fit itself succeeded and its results stand.
    """
    with tempfile.TemporaryDirectory(prefix=f"mocap-job-{job_id}-") as tmp:
        folder = Path(tmp)
        write_angles_csv(folder / "angles.csv", fit.model, result.fits, fit.clock)
        errors = []
        if overlay:
            errors += _drawn(job_id, folder / OVERLAY_DIR, lambda: overlay_job(fit, folder))
        if plots:
            errors += _drawn(job_id, folder / PLOTS_DIR, lambda: write_plots(
                folder / PLOTS_DIR, read_angles_csv(folder / "angles.csv"), fit.model, start,
                result.histograms))
        names = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")
                       if p.is_file() and NAME.match(p.relative_to(folder).as_posix()))
        for name in names:
            with (folder / name).open("rb") as f:
                storage.put(f"jobs/{job_id}/{name}", iter(partial(f.read, 1 << 20), b""))
    index: dict[str, object] = {"files": names, "error": "; ".join(errors) or None}
    storage.put(f"jobs/{job_id}/{INDEX}", [(json.dumps(index, indent=2) + "\n").encode()])
    return index


def _drawn(job_id: int, folder: Path, draw: Callable[[], object]) -> list[str]:
    """Run ``draw``, which writes into ``folder``. A failure is logged, its partial files are
    removed, and a message without server paths is returned, never raised: whatever breaks a
    drawing must not lose the fit it draws."""
    try:
        draw()
    except Exception as exc:
        logger.exception("job %s: %s not drawn", job_id, folder.name)
        shutil.rmtree(folder, ignore_errors=True)
        return [f"{folder.name} not drawn ({type(exc).__name__}; the worker's log says why)"]
    return []


def listed(storage: Storage, job_id: int) -> list[str]:
    """Names of the artifacts a job has (none when it asked for none)."""
    key = f"jobs/{job_id}/{INDEX}"
    if not storage.exists(key):
        return []
    with storage.open(key) as f:
        return [n for n in json.load(f)["files"] if NAME.match(n)]
