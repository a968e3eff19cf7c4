"""Screenshot of the lab dashboard from a real run: ``python docs/screenshot.py``.

Renders the demo's locust clip, starts ``mocap serve`` on the embedded default (SQLite,
filesystem broker, real worker processes) in a temporary directory, creates a lab,
uploads model, rig and video and fits them over HTTP (``mocap demo --service``'s steps),
submits a batch of two more trials, opens the dashboard in Debian's headless Chromium,
signs in with the lab's key, opens the finished job and saves ``docs/img/dashboard.png``.
Needs ``pip install -e '.[browser]'`` and ``apt-get install chromium``.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from playwright.sync_api import sync_playwright

from service.demo import _create_lab, _embedded_env, _fit_over_http, _free_port, _render, _wait_until_up

CHROMIUM = "/usr/bin/chromium"
# As root in a container, without a GPU, and with none of Chromium's own calls to the internet.
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "img" / "dashboard.png")
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--seed", type=int, default=2004)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="mocap-screenshot-") as tmp:
        root = Path(tmp)
        _, video = _render(root / "trial.avi", args.samples, args.seed)
        env = _embedded_env(root / "data")
        key = _create_lab(env)
        port = _free_port()
        with (root / "serve.log").open("w") as log:
            server = subprocess.Popen([sys.executable, "-m", "service.cli", "serve", "--port", str(port),
                                       "--workers", "2"], env=env, stdout=log, stderr=subprocess.STDOUT)
            try:
                base = f"http://127.0.0.1:{port}"
                with httpx.Client(base_url=f"{base}/v1", timeout=60.0,
                                  headers={"Authorization": f"Bearer {key}"}) as client:
                    _wait_until_up(client, server, root / "serve.log")
                    _fit_over_http(client, video, args.seed)
                    job_id = _submit_batch(client)
                _shoot(base, key, job_id, args.out)
            finally:
                server.send_signal(signal.SIGTERM)
                server.wait(timeout=90)
    print(f"saved {args.out} ({args.out.stat().st_size} bytes)")


def _submit_batch(client: httpx.Client) -> int:
    """A batch of two trials of the uploaded video with overlays and plots, awaited; returns
    the id of its first trial's job."""
    model, rig, video = (client.get(f"/{kind}").json()["items"][0]["id"]
                         for kind in ("models", "rigs", "videos"))
    options = {"chunk_size": 25, "overlay": True, "plots": True}
    batch = client.post("/batches", json={"model_id": model, "rig_id": rig, "options": options,
                                          "trials": [{"video_ids": [video]}, {"video_ids": [video]}]})
    batch.raise_for_status()
    while (status := client.get(f"/batches/{batch.json()['id']}").json()["status"]) == "running":
        time.sleep(0.5)
    print(f"batch {batch.json()['id']} {status}")
    # Newest first: the demo's own job is the oldest, the batch's first trial the one before it.
    return client.get("/jobs", params={"limit": 200}).json()["items"][-2]["id"]


def _shoot(base: str, key: str, job_id: int, out: Path) -> None:
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1100, "height": 900})
        page.goto(f"{base}/")
        page.get_by_label("Lab API key").fill(key)
        page.get_by_role("button", name="Sign in").click()
        page.get_by_role("link", name=f"Job {job_id}", exact=True).click()
        page.locator("#error-plot polyline").wait_for()
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out), full_page=True)
        browser.close()


if __name__ == "__main__":
    main()
