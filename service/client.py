"""A Python client of the ``/v1`` API: upload, submit, poll, download (``mocap remote`` runs on it).

Imports httpx and the standard library only (``pip install 'mocap[client]'``), so a notebook or a
lab's script can drive a remote service without the server's packages::

    with Client("http://fitting.lab:8000", load_key()) as api:
        model = api.upload_model(Path("model.xml"))
        rig = api.upload_rig(Path("rig.json"))
        video = api.upload_video(Path("trial1/cam0.avi"))
        job = api.submit_job(model["id"], rig["id"], [video["id"]])
        api.wait("job", job["id"])
        api.download("job", job["id"], Path("results"))

Every answer is the API's JSON as a dict (the OpenAPI description at ``/docs`` gives the fields).
Any 4xx or 5xx raises :class:`ApiError` carrying the server's ``detail``; an unreachable server
raises :class:`ClientError`; both print as one line.
"""

from __future__ import annotations

import json
import os
import time
import zipfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Literal

import httpx

Kind = Literal["job", "batch"]
TERMINAL = frozenset({"succeeded", "failed", "canceled"})
KEY_ENV = "MOCAP_API_KEY"
RESULT_FILES = ("angles.csv", "histograms.xml", "report.json")
MIN_POLL_S = 0.2  # the first poll's wait; it grows by half each poll up to the caller's maximum
_BLOCK = 1 << 20


class ClientError(Exception):
    """What the client could not do, in one line: an unreachable server, a bad key file, a timeout."""


class ApiError(ClientError):
    """The server answered 4xx or 5xx; ``detail`` is its explanation."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(f"{detail} (HTTP {status})")
        self.status, self.detail = status, detail


class WaitTimeoutError(ClientError):
    """A job or batch was not finished within the time :meth:`Client.wait` was given."""


def load_key(key_file: Path | None = None) -> str:
    """The API key from ``key_file`` if given, else from the environment variable ``MOCAP_API_KEY``.

    Never from the command line, where ``ps`` and shell histories would show it.
    """
    if key_file is not None:
        try:
            key = key_file.read_text(encoding="utf-8").strip()
        except (OSError, UnicodeDecodeError) as exc:
            raise ClientError(f"cannot read the key file {key_file}: "
                              f"{getattr(exc, 'strerror', None) or exc}") from None
        source = f"the key file {key_file}"
    else:
        key, source = os.environ.get(KEY_ENV, "").strip(), KEY_ENV
        if not key:
            raise ClientError(f"no API key: set {KEY_ENV} or pass --key-file PATH")
    if not key or not key.isascii() or any(c.isspace() for c in key):
        raise ClientError(f"{source} does not hold an API key (one line without spaces)")
    return key


def api_url(url: str) -> str:
    """``url`` as the API's base: ``http://host:8000`` and ``http://host:8000/v1/`` both give ``…/v1``."""
    url = url.strip().rstrip("/")
    if not url.startswith(("http://", "https://")):
        raise ClientError(f"the URL {url!r} does not start with http:// or https://")
    return url if url.endswith("/v1") else f"{url}/v1"


@dataclass
class Downloaded:
    """What :meth:`Client.download` did: archives fetched now, archives already complete on disk
    (kept, not fetched again), and jobs without results (one line each, e.g. "trial 2 (job 7) failed: …")."""

    fetched: list[Path] = field(default_factory=list)
    kept: list[Path] = field(default_factory=list)
    unfinished: list[str] = field(default_factory=list)


class Client:
    """A lab's connection to the service at ``url`` (``http://host:port`` or ``…/v1``) with its ``key``.

    ``timeout`` : seconds to wait for a connection or for each read or write (not a whole upload).
    """

    def __init__(self, url: str, key: str, *, timeout: float = 60.0) -> None:
        self.url = api_url(url)
        self._http = httpx.Client(base_url=self.url, timeout=timeout,
                                  headers={"Authorization": f"Bearer {key}"})

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def ping(self) -> None:
        """Return once the service answers this key; raise :class:`ClientError` if it cannot be
        reached, :class:`ApiError` if it refuses the key (401)."""
        self._send("GET", "/jobs", params={"limit": 1})

    # ---- uploads

    def upload_model(self, path: Path) -> dict[str, Any]:
        """Store a model.xml (FORMATS §1); the answer has its ``id``, ``name`` and ``dofs``."""
        return self._send("POST", "/models", content=_read(path), headers={"Content-Type": "application/xml"})

    def upload_rig(self, path: Path) -> dict[str, Any]:
        """Store a rig.json (FORMATS §2); the answer has its ``id``, ``views`` and ``videos`` (per trial)."""
        return self._send("POST", "/rigs", content=_read(path), headers={"Content-Type": "application/json"})

    def upload_video(self, path: Path, progress: Callable[[int], None] | None = None) -> dict[str, Any]:
        """Stream a video to the service; ``progress(n)`` is called with each block's byte count.

        The answer has its ``id``, ``frames`` (those that decode), ``fps`` and ``sha256``.
        """
        try:
            f = path.open("rb")
        except OSError as exc:
            raise ClientError(f"cannot read {path}: {exc.strerror}") from None
        with f:
            body = _Counted(f, progress or (lambda _n: None))
            return self._send("POST", "/videos",
                              files={"file": (path.name, body, "application/octet-stream")})

    # ---- jobs and batches

    def submit_job(self, model_id: int, rig_id: int, video_ids: Sequence[int],
                   options: dict[str, Any] | None = None) -> dict[str, Any]:
        """Submit one trial (one video per camera, in the rig's video order); the job as the API shows it.

        ``options`` : the API's JobOptions (as ``mocap fit``'s options), e.g. ``{"marker_diameter_px": 4}``.
        """
        return self._send("POST", "/jobs", json={"model_id": model_id, "rig_id": rig_id,
                                                 "video_ids": list(video_ids), "options": options or {}})

    def submit_batch(self, model_id: int, rig_id: int, trials: Sequence[Sequence[int]],
                     options: dict[str, Any] | None = None,
                     names: Sequence[str] | None = None) -> dict[str, Any]:
        """Submit one job per trial (each a list of video ids) sharing model, rig and ``options``;
        ``names`` (one per trial, optional) name the jobs and the trials' folders in the archive."""
        listed = [{"video_ids": list(ids)} for ids in trials]
        for trial, name in zip(listed, names or (), strict=False):
            trial["name"] = name
        return self._send("POST", "/batches", json={
            "model_id": model_id, "rig_id": rig_id, "options": options or {}, "trials": listed})

    def status(self, kind: Kind, ident: int) -> dict[str, Any]:
        """A job (``status``, ``progress``, ``error``) or a batch (the same summed, and its ``jobs``)."""
        return self._send("GET", f"/{_plural(kind)}/{ident}")

    def cancel(self, job_id: int) -> dict[str, Any]:
        """Cancel a job (workers stop between images); the job as the API shows it."""
        return self._send("POST", f"/jobs/{job_id}/cancel")

    def wait(self, kind: Kind, ident: int, *, timeout: float = 24 * 3600.0, max_interval: float = 5.0,
             unreachable_s: float = 120.0,
             on_poll: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
        """Poll until the job or batch is succeeded, failed or canceled; return its last status.

        Polls first after 0.2 s, then half as long again each time, at most every ``max_interval``
        seconds; ``on_poll`` sees every status. A service that cannot be reached is polled on (an
        API restarting does not end a wait of hours) until it has been so for ``unreachable_s``
        seconds; then that :class:`ClientError` is raised. Raises :class:`WaitTimeoutError` after
        ``timeout`` seconds, an :class:`ApiError` at once.
        """
        deadline, interval, down_since = time.monotonic() + timeout, MIN_POLL_S, None
        while True:
            try:
                state: dict[str, Any] | None = self.status(kind, ident)
                down_since = None
            except ApiError:
                raise
            except ClientError:
                down_since = down_since or time.monotonic()
                if time.monotonic() - down_since >= unreachable_s:
                    raise
                state = None
            if state is not None and on_poll is not None:
                on_poll(state)
            if state is not None and state["status"] in TERMINAL:
                return state
            left = deadline - time.monotonic()
            if left <= 0:
                now = state["status"] if state is not None else "not known (the service is unreachable)"
                raise WaitTimeoutError(f"{kind} {ident} is still {now} after {timeout:g} s")
            time.sleep(min(interval, left))
            interval = min(interval * 1.5, max(max_interval, MIN_POLL_S))

    def result(self, job_id: int, name: str) -> bytes:
        """One result file of a succeeded job: ``angles.csv``, ``histograms.xml`` or ``report.json``."""
        if name not in RESULT_FILES:
            raise ClientError(f"{name!r} is not a result file: one of {', '.join(RESULT_FILES)}")
        return self._request("GET", f"/jobs/{job_id}/{name}").content

    def download(self, kind: Kind, ident: int, out: Path,
                 on_archive: Callable[[Path, bool], None] | None = None) -> Downloaded:
        """Each succeeded job's archive (results, exports, model, rig) into directory ``out``.

        A job's archive is ``job-<id>.zip``; a batch's jobs give ``trial-<NNN>-job-<id>.zip`` (the
        folder names of the batch's own archive). Resumable at file granularity: an archive is
        written to ``<name>.part`` and renamed once whole, and an archive already in ``out`` whose
        every member passes its CRC-32 is kept, not fetched again; a partial or damaged one is
        fetched again. ``on_archive(path, fetched)`` is called as each is done.
        """
        state = self.status(kind, ident)
        jobs = state["jobs"] if kind == "batch" else [state]
        out.mkdir(parents=True, exist_ok=True)
        done = Downloaded()
        for job in jobs:
            trial = f"trial {job['trial']} (job {job['id']})" if kind == "batch" else f"job {job['id']}"
            if job["status"] != "succeeded":
                done.unfinished.append(f"{trial} is {job['status']}"
                                       + (f": {job['error']}" if job.get("error") else ""))
                continue
            path = out / (f"trial-{job['trial']:03d}-job-{job['id']}.zip" if kind == "batch"
                          else f"job-{job['id']}.zip")
            fetched = not archive_complete(path)
            if fetched:
                self._fetch(f"/jobs/{job['id']}/archive.zip", path)
            (done.fetched if fetched else done.kept).append(path)
            if on_archive is not None:
                on_archive(path, fetched)
        return done

    # ---- HTTP

    def _fetch(self, route: str, path: Path) -> None:
        """Stream ``route`` to ``path`` through ``path.part``, renamed only when complete."""
        part = path.with_name(path.name + ".part")
        with self._stream("GET", route) as response, part.open("wb") as f:
            for block in response.iter_bytes(_BLOCK):
                f.write(block)
        if not archive_complete(part):
            raise ClientError(f"the archive from {route} arrived damaged; run the download again")
        part.replace(path)

    def _send(self, method: str, route: str, **kwargs: Any) -> dict[str, Any]:
        return self._request(method, route, **kwargs).json()

    def _request(self, method: str, route: str, **kwargs: Any) -> httpx.Response:
        with self._stream(method, route, **kwargs) as response:
            response.read()
            return response

    @contextmanager
    def _stream(self, method: str, route: str, **kwargs: Any) -> Iterator[httpx.Response]:
        """A response with a 2xx status, its body not yet read; anything else raises one line."""
        try:
            with self._http.stream(method, route, **kwargs) as response:
                if response.is_error:
                    response.read()
                    raise ApiError(response.status_code, _detail(response))
                yield response
        except httpx.TimeoutException:
            raise ClientError(f"{self.url}{route}: no answer within {self._http.timeout.read:g} s") from None
        except httpx.ConnectError as exc:
            raise ClientError(f"cannot reach {self.url}: {exc}") from None
        except httpx.TransportError as exc:  # the connection broke: run the command again
            raise ClientError(f"the connection to {self.url} broke during {method} {route}: {exc}") from None


class _Counted:
    """A binary file whose reads are reported to ``progress`` (httpx streams a multipart file by reads)."""

    def __init__(self, f: BinaryIO, progress: Callable[[int], None]) -> None:
        self._f, self._progress = f, progress

    def read(self, size: int = -1) -> bytes:
        block = self._f.read(size)
        self._progress(len(block))
        return block

    def fileno(self) -> int:  # httpx sizes the body from it: a Content-Length, not chunked
        return self._f.fileno()

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._f.seek(offset, whence)

    def tell(self) -> int:
        return self._f.tell()


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ClientError(f"cannot read {path}: {exc.strerror}") from None


def _plural(kind: Kind) -> str:
    if kind not in ("job", "batch"):
        raise ClientError(f"{kind!r} is neither 'job' nor 'batch'")
    return "jobs" if kind == "job" else "batches"


def _detail(response: httpx.Response) -> str:
    """The server's ``detail``, or the first line of a body that is not the API's JSON (a proxy's page)."""
    try:
        detail = response.json()["detail"]
    except (json.JSONDecodeError, KeyError, TypeError, UnicodeDecodeError):
        text = response.text.strip().splitlines()
        detail = text[0][:200] if text else response.reason_phrase
    if not isinstance(detail, str):
        detail = json.dumps(detail)
    return detail.replace("\n", " ")


def archive_complete(path: Path) -> bool:
    """Whether ``path`` is a whole zip whose every member matches its CRC-32."""
    try:
        with zipfile.ZipFile(path) as archive:
            return archive.testzip() is None
    except (OSError, zipfile.BadZipFile, EOFError):
        return False
