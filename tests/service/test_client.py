"""service.client and ``mocap remote`` against the real embedded service (``mocap serve``: SQLite,
filesystem broker, worker processes), run as a lab runs them: the CLI in a subprocess, the key in
the environment or a file."""

from __future__ import annotations

import hashlib
import io
import os
import re
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest
import typer.main
from conftest import free_port, serve_embedded

from core.examples import LOCUST
from core.results import read_angles_csv
from service.cli import app
from service.client import ApiError, Client, WaitTimeoutError

pytestmark = [pytest.mark.service, pytest.mark.slow]  # the embedded service and its workers fit
OPTIONS = '{"marker_diameter_px": 4, "chunk_size": 20}'
ONE_ERROR_LINE = re.compile(r"mocap: error: [^\n]+\n")


def remote(*args: str, key: str | None, url: str, terminal: bool = False) -> subprocess.CompletedProcess:
    """``mocap remote ARGS --url URL`` with ``key`` in MOCAP_API_KEY (None: no key in the environment);
    ``terminal``: rich draws its bars as on a terminal (TTY_COMPATIBLE=1; 0 overrides a FORCE_COLOR)."""
    env = {k: v for k, v in os.environ.items() if k != "MOCAP_API_KEY"}
    env["TTY_COMPATIBLE"] = "1" if terminal else "0"
    if key is not None:
        env["MOCAP_API_KEY"] = key
    return subprocess.run([sys.executable, "-m", "service.cli", "remote", *args, "--url", url],
                          env=env, capture_output=True, text=True, timeout=900)


def assert_one_error_line(done: subprocess.CompletedProcess, *words: str) -> None:
    assert done.returncode == 2, done.stdout + done.stderr
    assert ONE_ERROR_LINE.fullmatch(done.stderr), done.stderr
    for word in words:
        assert word in done.stderr, done.stderr


@pytest.fixture(scope="module")
def key(embedded) -> str:
    return embedded.create_lab("client").headers["Authorization"].removeprefix("Bearer ")


@pytest.fixture(scope="module")
def trials(clip, tmp_path_factory) -> Path:
    """Two trial folders as ``mocap synth`` writes them: the clip's video and a truth.csv (ignored)."""
    folder = tmp_path_factory.mktemp("trials")
    for name in ("trial-a", "trial-b"):
        (folder / name).mkdir()
        shutil.copy(clip.video, folder / name / "video0.avi")
        (folder / name / "truth.csv").write_text("not a video\n")
    return folder


@pytest.fixture(scope="module")
def fitted(embedded, key, trials, tmp_path_factory) -> tuple[int, Path]:
    """``mocap remote upload`` → ``wait`` → ``download`` of the two trials: the batch id and the folder."""
    example = ("--model", str(LOCUST / "model.xml"), "--rig", str(LOCUST / "rig.json"))
    uploaded = remote("upload", str(trials), *example, "--options", OPTIONS, key=key, url=embedded.url,
                      terminal=True)
    assert uploaded.returncode == 0, uploaded.stdout + uploaded.stderr
    assert "uploading trial-b/video0.avi" in uploaded.stderr  # the bar, drawn on stderr
    assert re.search(r"uploaded 2 video\(s\) of 2 trial\(s\)", uploaded.stdout), uploaded.stdout
    assert re.search(r"trial-a: job \d+\n  trial-b: job \d+\n", uploaded.stdout), uploaded.stdout
    batch = int(re.search(r"batch (\d+) submitted: 2 trial\(s\)", uploaded.stdout)[1])
    # 600 s: a first run compiles the kernels (minutes of CPU, more on a shared machine)
    waited = remote("wait", "batch", str(batch), "--timeout", "600", "--interval", "0.5",
                    key=key, url=embedded.url, terminal=True)
    assert waited.returncode == 0, waited.stdout + waited.stderr
    assert f"batch {batch} running (images)" in waited.stderr  # the bar of fitted images
    assert f"batch {batch} succeeded: 80/80 images" in waited.stdout
    out = tmp_path_factory.mktemp("download")
    downloaded = remote("download", "batch", str(batch), "--out", str(out), key=key, url=embedded.url)
    assert downloaded.returncode == 0, downloaded.stdout + downloaded.stderr
    assert downloaded.stdout.count("downloaded ") == 2, downloaded.stdout
    for done in (uploaded, waited, downloaded):
        assert key not in done.stdout + done.stderr
    return batch, out


def angles_rmse(archive: Path, truth: np.ndarray, tmp: Path) -> np.ndarray:
    with zipfile.ZipFile(archive) as z:
        (tmp / "angles.csv").write_bytes(z.read("angles.csv"))
    return np.sqrt(np.mean((read_angles_csv(tmp / "angles.csv").dofs - truth) ** 2, axis=0))


def test_a_folder_of_trials_is_uploaded_fitted_and_downloaded_as_one_batch(fitted, clip, tmp_path):
    _, out = fitted
    archives = sorted(out.iterdir())
    assert [re.sub(r"job-\d+", "job-N", p.name) for p in archives] == [
        "trial-000-job-N.zip", "trial-001-job-N.zip"]
    for archive in archives:
        with zipfile.ZipFile(archive) as z:
            names = set(z.namelist())
        assert {"angles.csv", "histograms.xml", "report.json", "model.xml", "rig.json"} <= names
        assert np.all(angles_rmse(archive, clip.truth, tmp_path) < 0.5)


def test_an_interrupted_download_keeps_whole_archives_and_fetches_the_rest_again(embedded, key, fitted):
    batch, out = fitted
    whole, cut = sorted(out.iterdir())
    kept_at, original = whole.stat().st_mtime_ns, cut.read_bytes()
    cut.write_bytes(original[: len(original) // 2])  # a copy interrupted half-way
    (out / (whole.name + ".part")).write_bytes(b"PK")  # a leftover of an earlier interruption
    again = remote("download", "batch", str(batch), "--out", str(out), key=key, url=embedded.url)
    assert again.returncode == 0, again.stdout + again.stderr
    assert f"kept {whole} (already complete)" in again.stdout
    assert f"downloaded {cut}" in again.stdout
    assert whole.stat().st_mtime_ns == kept_at  # not written again
    with zipfile.ZipFile(cut) as fetched, zipfile.ZipFile(io.BytesIO(original)) as first:
        assert fetched.testzip() is None
        assert fetched.read("angles.csv") == first.read("angles.csv")
    finished = remote("download", "batch", str(batch), "--out", str(out), key=key, url=embedded.url)
    assert finished.stdout.count("already complete") == 2 and "downloaded" not in finished.stdout


def test_status_and_wait_of_a_finished_batch_and_a_key_file(embedded, key, fitted, tmp_path):
    batch, _ = fitted
    key_file = tmp_path / "key"
    key_file.write_text(key + "\n")
    shown = remote("status", "batch", str(batch), "--key-file", str(key_file), key=None, url=embedded.url)
    assert shown.returncode == 0, shown.stderr
    assert re.match(rf"batch {batch} succeeded: 80/80 images, \d+ over threshold, jobs 2 succeeded\n"
                    r"  trial 0: job \d+ succeeded: 40/40 images", shown.stdout), shown.stdout


@pytest.mark.parametrize("case", ["bad key", "no key", "unknown job", "unknown batch", "refused",
                                  "broken model", "not a video", "wrong video count", "options not JSON",
                                  "key as an option"])
def test_each_mistake_is_one_line_and_exit_2(embedded, key, trials, tmp_path, case):
    example = ["--model", str(LOCUST / "model.xml"), "--rig", str(LOCUST / "rig.json")]
    url, use_key, args = embedded.url, key, ["status", "job", "1"]
    if case == "bad key":
        use_key, expect = "0" * 43, ["unknown API key (HTTP 401)"]
    elif case == "no key":
        use_key, expect = None, ["no API key: set MOCAP_API_KEY or pass --key-file PATH"]
    elif case == "unknown job":
        args, expect = ["wait", "job", "999999"], ["job 999999 not found (HTTP 404)"]
    elif case == "unknown batch":
        args, expect = ["download", "batch", "999999", "--out", str(tmp_path)], ["batch 999999 not found"]
    elif case == "refused":
        url, expect = f"http://127.0.0.1:{free_port()}", ["cannot reach", "Connection refused"]
    elif case == "broken model":
        (tmp_path / "model.xml").write_text("<model><segment name='femur'>")
        example[1] = str(tmp_path / "model.xml")
        args, expect = ["upload", str(trials), *example], ["(HTTP 422)"]
    elif case == "not a video":
        shutil.copytree(trials, tmp_path / "trials")
        (tmp_path / "trials/0-first").mkdir()
        (tmp_path / "trials/0-first/video0.avi").write_bytes(b"RIFF" + bytes(5000))  # sorts first
        args, expect = ["upload", str(tmp_path / "trials"), *example], ["0-first/video0.avi: ", "(HTTP 422)"]
    elif case == "wrong video count":
        shutil.copytree(trials, tmp_path / "trials")
        shutil.copy(tmp_path / "trials/trial-a/video0.avi", tmp_path / "trials/trial-b/video1.avi")
        args = ["upload", str(tmp_path / "trials"), *example]
        expect = ["the rig needs 1 video(s) per trial", "trial-b has 2", "nothing was uploaded"]
    elif case == "options not JSON":
        args, expect = ["upload", str(trials), *example, "--options", "seed=1"], ["--options is not JSON"]
    else:
        args, expect = ["status", "job", "1", "--key", key], ["No such option: --key"]
    videos_before = _videos(embedded, key)
    done = remote(*args, key=use_key, url=url)
    assert_one_error_line(done, *expect)
    assert key not in done.stdout + done.stderr
    assert _videos(embedded, key) == videos_before  # a refused upload sends no video


def test_a_batch_refused_after_the_upload_says_how_to_submit_the_uploaded_videos(embedded, key, trials):
    example = ["--model", str(LOCUST / "model.xml"), "--rig", str(LOCUST / "rig.json")]
    refused = remote("upload", str(trials), *example, "--options", '{"seeed": 1}', key=key, url=embedded.url)
    assert_one_error_line(refused, "options.seeed: Extra inputs are not permitted")
    again = re.search(r"submit them with mocap remote (submit .*) --options '\{…\}' \(HTTP 422\)",
                      refused.stderr)
    assert again, refused.stderr
    submitted = remote(*again[1].split(), key=key, url=embedded.url)
    assert submitted.returncode == 0, submitted.stderr
    assert re.match(r"batch \d+ submitted: jobs \d+, \d+;", submitted.stdout), submitted.stdout


def test_no_remote_command_takes_the_key_itself():
    group = typer.main.get_command(app).commands["remote"]
    for name, command in group.commands.items():
        options = {o for p in command.params for o in p.opts}
        assert "--key-file" in options, name
        assert not any("key" in o and o != "--key-file" for o in options), (name, options)
        assert not any(p.envvar and "KEY" in str(p.envvar) for p in command.params), name


def test_wait_warns_when_most_of_a_jobs_images_are_over_the_threshold(embedded, key, clip):
    """report.json's advice (``core.pipeline.over_threshold_advice``) reaches a remote user: a threshold
    no fit meets puts every image over it; the clip's own job (its threshold the default) has none."""
    with Client(embedded.url, key) as api:
        video = api.upload_video(clip.video)
        model, rig = api.upload_model(LOCUST / "model.xml"), api.upload_rig(LOCUST / "rig.json")
        options = {"marker_diameter_px": 4, "max_attempts": 1}
        strict, default = (api.submit_job(model["id"], rig["id"], [video["id"]], {**options, **extra})["id"]
                           for extra in ({"error_threshold_px": 0.001}, {}))
    warned = remote("wait", "job", str(strict), "--interval", "0.5", key=key, url=embedded.url)
    assert warned.returncode == 0, warned.stdout + warned.stderr
    line = (rf"mocap: warning: job {strict}: 40 of 40 images are over the threshold \(median [0-9.]+ px per "
            r"marker projection, threshold 0.001\): check [^\n]+ \(the job option \"overlay\": true; "
            r"docs/SEEING_THE_FIT.md\)\n")
    assert re.fullmatch(line, warned.stderr), warned.stderr
    quiet = remote("wait", "job", str(default), "--interval", "0.5", key=key, url=embedded.url)
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr


def test_a_canceled_job_is_exit_1_from_wait_and_download(embedded, key, clip, tmp_path):
    with Client(embedded.url, key) as api:
        video = api.upload_video(clip.video)
        model, rig = api.upload_model(LOCUST / "model.xml"), api.upload_rig(LOCUST / "rig.json")
        job = api.submit_job(model["id"], rig["id"], [video["id"]])["id"]
        assert api.cancel(job)["status"] == "canceled"
    waited = remote("wait", "job", str(job), key=key, url=embedded.url)
    assert waited.returncode == 1 and waited.stdout.startswith(f"job {job} canceled:"), waited.stdout
    downloaded = remote("download", "job", str(job), "--out", str(tmp_path), key=key, url=embedded.url)
    assert downloaded.returncode == 1, downloaded.stdout + downloaded.stderr
    assert downloaded.stdout == f"no results: job {job} is canceled: canceled by the user\n"
    assert list(tmp_path.iterdir()) == []


def test_wait_outlasts_a_restart_of_the_service(clip, tmp_path):
    """The API stopped and started again (now with a worker) while ``mocap remote wait`` polls: the
    wait polls on through the outage and ends with the job's result."""
    data, port = tmp_path / "data", free_port()
    service = serve_embedded(data, port, workers=0)  # no worker yet: the job stays queued
    try:
        key = service.create_lab("restart").headers["Authorization"].removeprefix("Bearer ")
        with Client(service.url, key) as api:
            model, rig = api.upload_model(LOCUST / "model.xml"), api.upload_rig(LOCUST / "rig.json")
            video = api.upload_video(clip.video)
            job = api.submit_job(model["id"], rig["id"], [video["id"]], {"marker_diameter_px": 4})["id"]
        env = {**os.environ, "MOCAP_API_KEY": key, "TTY_COMPATIBLE": "0"}
        waiting = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "remote", "wait", "job", str(job), "--interval", "1",
             "--url", service.url], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(3)
        service.stop()
        assert waiting.poll() is None  # polling a service that is down
        time.sleep(2)
        service = serve_embedded(data, port, workers=1)
        out, err = waiting.communicate(timeout=600)
    finally:
        service.stop()
    assert waiting.returncode == 0, out + err
    assert out.startswith(f"job {job} succeeded: 40/40 images"), out


def test_the_client_reports_upload_progress_and_wait_times_out(embedded, key, clip):
    with Client(embedded.url.removesuffix("/v1"), key) as api:
        sent: list[int] = []
        video = api.upload_video(clip.video, progress=sent.append)
        assert sum(sent) == clip.video.stat().st_size and len(sent) > 1
        assert video["sha256"] == hashlib.sha256(clip.video.read_bytes()).hexdigest()
        model, rig = api.upload_model(LOCUST / "model.xml"), api.upload_rig(LOCUST / "rig.json")
        job = api.submit_job(model["id"], rig["id"], [video["id"]], {"marker_diameter_px": 4})
        with pytest.raises(WaitTimeoutError, match=rf"job {job['id']} is still \w+ after 0 s"):
            api.wait("job", job["id"], timeout=0)
        seen: list[str] = []
        done = api.wait("job", job["id"], timeout=600, max_interval=0.5,
                        on_poll=lambda state: seen.append(state["status"]))
        assert done["status"] == "succeeded" and seen[-1] == "succeeded"
        assert api.result(job["id"], "angles.csv").startswith(b"sample")
        with pytest.raises(ApiError, match="model 999999 not found") as refused:
            api.submit_job(999999, rig["id"], [video["id"]])
        assert refused.value.status == 404


def _videos(embedded, key: str) -> int:
    listed = httpx.get(embedded.url + "/videos", params={"limit": 200},
                       headers={"Authorization": f"Bearer {key}"})
    return len(listed.json()["items"])


def test_upload_prints_the_model_warnings_of_the_service(embedded, key, trials, tmp_path):
    """A model whose markers leave a DOF undetermined is stored, and ``mocap remote upload``
    says so in the lab's terms (its file, the DOF, the fix) before it goes on."""
    claw = tmp_path / "claw.xml"
    claw.write_text((LOCUST / "model.xml").read_text().replace(
        "  <marker", '  <joint name="claw" parent="tarsus"><offset x="3"/>'
        '<dof axis="z" name="claw_z" min="-30" max="30"/></joint>\n  <marker', 1))
    # Options the server refuses: the batch stops after the upload, no fit is run.
    done = remote("upload", str(trials), "--model", str(claw), "--rig", str(LOCUST / "rig.json"),
                  "--options", '{"seeed": 1}', key=key, url=embedded.url)
    assert "  claw.xml: warning: claw_z moves no marker: add a marker to segment claw\n" in done.stdout, \
        done.stdout
