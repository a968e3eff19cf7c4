"""``mocap remote``: drive a service over HTTP with :mod:`service.client` (upload, submit, status,
wait, download).

The key comes from ``MOCAP_API_KEY`` or ``--key-file``, never from an option's value. This
module imports typer, rich and core's CLI helpers only; httpx (``service.client``) is imported by
the commands, so ``mocap`` itself runs where httpx is not installed.

Folder layout of ``upload``: one subfolder per trial, holding one video per camera; the videos
sorted by name are the rig's videos 0, 1, … (``trial-01/cam0.avi``, ``trial-01/cam1.avi``, …).
Files without a video suffix (``truth.csv``, notes) and hidden entries are ignored.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, DownloadColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn

from cli.app import user_errors

if TYPE_CHECKING:
    from service.client import Client

remote = typer.Typer(no_args_is_help=True, help="Use a mocap service over HTTP (key: MOCAP_API_KEY or "
                     "--key-file).")

VIDEO_SUFFIXES = frozenset({".avi", ".mp4", ".mov", ".mkv", ".m4v", ".dv", ".mpg", ".mpeg", ".wmv", ".webm"})


class Kind(StrEnum):
    job = "job"
    batch = "batch"


Url = Annotated[str, typer.Option(envvar="MOCAP_URL", help="the service, e.g. http://host:8000 (or …/v1)")]
KeyFile = Annotated[Path | None, typer.Option(
    help="a file holding the lab's API key (else MOCAP_API_KEY); there is no option taking the key "
    "itself, which ps and shell histories would show")]
Options = Annotated[str | None, typer.Option(
    help='job options as JSON, as the API\'s JobOptions: \'{"marker_diameter_px": 4, "seed": 1}\'')]
KindArg = Annotated[Kind, typer.Argument(help="job or batch")]
IdArg = Annotated[int, typer.Argument(min=1, help="its id")]
DEFAULT_URL = "http://127.0.0.1:8000"


@remote.command()
def upload(
    folder: Annotated[Path, typer.Argument(help="one subfolder per trial, one video per camera in each")],
    model: Annotated[Path, typer.Option(help="model.xml")],
    rig: Annotated[Path, typer.Option(help="rig.json")],
    options: Options = None,
    url: Url = DEFAULT_URL,
    key_file: KeyFile = None,
) -> None:
    """Upload model, rig and every trial's videos of FOLDER, and submit them as one batch."""
    with _client(url, key_file) as api:
        trials = trial_videos(folder)
        job_options = _options(options)
        stored_model, stored_rig = api.upload_model(model), api.upload_rig(rig)
        print(f"model {stored_model['id']} ({stored_model['name']}), rig {stored_rig['id']} "
              f"({len(stored_rig['views'])} views in {stored_rig['videos']} video(s) per trial)")
        for line in stored_model.get("warnings", []):
            print(f"  {model.name}: warning: {line}")
        _check_counts(trials, stored_rig["videos"], folder)
        video_ids = _upload_trials(api, trials)
        batch = _submit_uploaded(api, stored_model["id"], stored_rig["id"], video_ids, job_options,
                                 names=[name[:200] for name in trials])
        for name, job in zip(trials, batch["jobs"], strict=True):
            print(f"  {name}: job {job['id']}")
        print(f"batch {batch['id']} submitted: {len(batch['jobs'])} trial(s); "
              f"follow it with: mocap remote wait batch {batch['id']}")


@remote.command()
def submit(
    model_id: Annotated[int, typer.Option(min=1, help="an uploaded model's id")],
    rig_id: Annotated[int, typer.Option(min=1, help="an uploaded rig's id")],
    trial: Annotated[list[str], typer.Option(help="a trial's video ids in the rig's order, e.g. 4,5; "
                                             "repeat for a batch")],
    options: Options = None,
    url: Url = DEFAULT_URL,
    key_file: KeyFile = None,
) -> None:
    """Submit uploaded videos: one --trial is a job, several are a batch."""
    with _client(url, key_file) as api:
        trials = [_ids(t) for t in trial]
        job_options = _options(options)
        if len(trials) == 1:
            job = api.submit_job(model_id, rig_id, trials[0], job_options)
            print(f"job {job['id']} submitted; follow it with: mocap remote wait job {job['id']}")
            return
        batch = api.submit_batch(model_id, rig_id, trials, job_options)
        print(f"batch {batch['id']} submitted: jobs {', '.join(str(j['id']) for j in batch['jobs'])}; "
              f"follow it with: mocap remote wait batch {batch['id']}")


@remote.command()
def status(kind: KindArg, ident: IdArg, url: Url = DEFAULT_URL, key_file: KeyFile = None) -> None:
    """Print a job's or batch's status and progress (a batch: one line per job too)."""
    with _client(url, key_file) as api:
        state = api.status(kind.value, ident)
        print(_summary(kind, state))
        for job in state.get("jobs", []):
            print(f"  trial {job['trial']}: {_summary(Kind.job, job)}")


@remote.command()
def wait(
    kind: KindArg, ident: IdArg,
    timeout: Annotated[float, typer.Option(min=0, help="seconds to wait at most")] = 24 * 3600.0,
    interval: Annotated[float, typer.Option(min=0.2, max=300, help="seconds between polls at most")] = 5.0,
    url: Url = DEFAULT_URL, key_file: KeyFile = None,
) -> None:
    """Wait for a job or batch to finish, with a progress bar; exit 1 unless it succeeded."""
    with _client(url, key_file) as api, _bar(MofNCompleteColumn()) as bar:
        task = bar.add_task(f"{kind.value} {ident}", total=None)

        def show(state: dict[str, Any]) -> None:
            done = state["progress"]
            bar.update(task, completed=done["images_done"], total=done["images_total"] or None,
                       description=f"{kind.value} {ident} {state['status']} (images)")

        state = api.wait(kind.value, ident, timeout=timeout, max_interval=interval, on_poll=show)
        advice = _advice(api, state)
    print(_summary(kind, state))
    for line in advice:
        typer.echo(line, err=True)
    if state["status"] != "succeeded":
        for job in state.get("jobs", [state]):
            if job["status"] != "succeeded":
                print(f"  {_summary(Kind.job, job)}")
        raise typer.Exit(1)


@remote.command()
def download(
    kind: KindArg, ident: IdArg,
    out: Annotated[Path, typer.Option(help="directory for the archives")],
    url: Url = DEFAULT_URL, key_file: KeyFile = None,
) -> None:
    """Download the archive of a job, or of each job of a batch; archives already complete in OUT are
    kept, so an interrupted download resumes by running it again. Exit 1 if a job has no results."""
    with _client(url, key_file) as api, _bar(MofNCompleteColumn()) as bar:
        state = api.status(kind.value, ident)
        task = bar.add_task("archives", total=len(state.get("jobs", [state])))
        done = api.download(kind.value, ident, out, on_archive=lambda _p, _f: bar.advance(task))
    for path in done.fetched:
        print(f"downloaded {path}")
    for path in done.kept:
        print(f"kept {path} (already complete)")
    for line in done.unfinished:
        print(f"no results: {line}")
    if done.unfinished:
        raise typer.Exit(1)


def trial_videos(folder: Path) -> dict[str, list[Path]]:
    """Each trial subfolder's name and its videos sorted by name (the rig's video order)."""
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder (one subfolder per trial, one video per camera in each)")
    subfolders = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not subfolders:
        raise ValueError(f"{folder} has no trial subfolders (one per trial, one video per camera in each)")
    trials = {d.name: sorted(p for p in d.iterdir() if p.is_file() and not p.name.startswith(".")
                             and p.suffix.lower() in VIDEO_SUFFIXES) for d in subfolders}
    if empty := [name for name, videos in trials.items() if not videos]:
        raise ValueError(f"trial folder(s) without videos ({', '.join(sorted(VIDEO_SUFFIXES))}): "
                         + ", ".join(empty))
    return trials


def _submit_uploaded(api: Client, model_id: int, rig_id: int, video_ids: list[list[int]],
                     options: dict[str, Any], names: list[str]) -> dict[str, Any]:
    """Submit the uploaded trials as a batch; if the server refuses it, the one error line also says
    how to submit the videos again without uploading them again."""
    from service.client import ApiError

    try:
        return api.submit_batch(model_id, rig_id, video_ids, options, names)
    except ApiError as exc:
        again = " ".join(f"--trial {','.join(map(str, ids))}" for ids in video_ids)
        raise ApiError(exc.status, f"{exc.detail}; the videos are uploaded: once fixed, submit them with "
                       f"mocap remote submit --model-id {model_id} --rig-id {rig_id} {again}"
                       + (" --options '{…}'" if options else "")) from None


def _check_counts(trials: dict[str, list[Path]], per_trial: int, folder: Path) -> None:
    wrong = [f"{name} has {len(videos)}" for name, videos in trials.items() if len(videos) != per_trial]
    if wrong:
        raise ValueError(f"the rig needs {per_trial} video(s) per trial, but in {folder}: "
                         + "; ".join(wrong) + " (nothing was uploaded but model and rig)")


def _upload_trials(api: Client, trials: dict[str, list[Path]]) -> list[list[int]]:
    """Upload every trial's videos with one bar over all their bytes; the video ids per trial."""
    from service.client import ApiError

    total = sum(p.stat().st_size for videos in trials.values() for p in videos)
    ids: list[list[int]] = []
    warnings: list[str] = []  # printed below the bar, once it is gone
    with _bar(DownloadColumn()) as bar:
        task = bar.add_task("uploading", total=total)
        for name, videos in trials.items():
            ids.append([])
            for video in videos:
                bar.update(task, description=f"uploading {name}/{video.name}")
                try:
                    stored = api.upload_video(video, progress=lambda n: bar.advance(task, n))
                except ApiError as exc:  # which of the folder's videos, in the user's terms
                    raise ApiError(exc.status, f"{name}/{video.name}: {exc.detail}") from None
                ids[-1].append(stored["id"])
                if stored.get("warning"):
                    warnings.append(f"  {name}/{video.name}: {stored['warning']}")
    print(f"uploaded {sum(map(len, ids))} video(s) of {len(ids)} trial(s), {total / 1e6:.1f} MB")
    print(*warnings, sep="\n", end="\n" if warnings else "")
    return ids


@contextmanager
def _client(url: str, key_file: Path | None) -> Iterator[Client]:
    """A client on ``url``; any error of the client or the user's files is one line and exit 2."""
    try:
        from service.client import Client, ClientError, load_key
    except ModuleNotFoundError as exc:
        typer.echo(f"mocap: error: mocap remote needs {exc.name}: python3 -m pip install 'mocap[client]'",
                   err=True)
        raise typer.Exit(2) from None
    with user_errors(ClientError), Client(url, load_key(key_file)) as api:
        yield api


@contextmanager
def _bar(counter: ProgressColumn) -> Iterator[Progress]:
    """A rich progress bar on stderr when it is a terminal; nothing shown otherwise."""
    console = Console(stderr=True)
    with Progress(TextColumn("{task.description}"), BarColumn(), counter, console=console,
                  transient=True, disable=not console.is_terminal) as bar:
        yield bar


def _options(text: str | None) -> dict[str, Any]:
    if text is None:
        return {}
    try:
        options = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--options is not JSON: {exc}") from None
    if not isinstance(options, dict):
        raise ValueError('--options must be a JSON object, e.g. \'{"seed": 1}\'')
    return options


def _ids(text: str) -> list[int]:
    try:
        return [int(part) for part in text.split(",")]
    except ValueError:
        raise ValueError(f"--trial {text!r} is not video ids separated by commas, e.g. 4,5") from None


def _advice(api: Client, state: dict[str, Any]) -> list[str]:
    """Each succeeded job's ``report.json`` advice (``core.pipeline``: most images over the
    threshold, or else ambiguous), as warning lines naming the job and where to see the images."""
    lines = []
    for job in state.get("jobs", [state]):
        if job["status"] == "succeeded":
            report = json.loads(api.result(job["id"], "report.json"))
            lines += [f"mocap: warning: job {job['id']}: {line} (the job option \"overlay\": true; "
                      f"docs/SEEING_THE_FIT.md)" for line in report["advice"]]
    return lines


def _summary(kind: Kind, state: dict[str, Any]) -> str:
    done = state["progress"]
    line = (f"{kind.value} {state['id']} {state['status']}: {done['images_done']}/{done['images_total']} "
            f"images, {done['images_over_threshold']} over threshold")
    if kind is Kind.batch:
        line += ", jobs " + ", ".join(f"{n} {s}" for s, n in sorted(state["statuses"].items()))
    if state.get("error"):
        line += f"; {state['error']}"
    return line

