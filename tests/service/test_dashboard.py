"""The lab dashboard (``/``) and the API docs (``/docs``, ``/redoc``) in a real headless browser.

Debian's Chromium driven by Playwright against ``mocap serve`` (embedded: SQLite, filesystem
broker, real worker processes): sign in with a lab's key, watch a running job's progress
advance, open a finished job (error plot, images by status, artifacts when it has them),
download angles.csv; another lab's key sees none of it; the docs render with every request
to another host refused. With ``CI=true`` a missing Chromium or Playwright fails these tests.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest
from svc_helpers import repeated, slow_rig, submit, upload_inputs, wait_for

from core.examples import LOCUST

pytestmark = [pytest.mark.service, pytest.mark.browser, pytest.mark.slow]

CHROMIUM = "/usr/bin/chromium"
# As root in a container, without a GPU, and with none of Chromium's own calls to the internet.
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
WAIT_MS = 20_000


def _require_browser() -> None:
    """Chromium and Playwright, or a failure (CI) / skip (laptop) saying how to install them."""
    missing = [] if shutil.which(CHROMIUM) else ["chromium (apt-get install chromium)"]
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing.append("playwright (pip install -e '.[browser]')")
    if not missing:
        return
    message = f"missing for the browser tests: {', '.join(missing)}"
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(message)
    pytest.skip(message)


@pytest.fixture(scope="module")
def browser() -> Iterator:
    _require_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()


@pytest.fixture(scope="module")
def lab(embedded, clip):
    """Lab "dashboard": its key, model, rig, video, a succeeded job, with overlay and plot
    artifacts where the service offers them (options.overlay, options.plots), and a succeeded
    batch of two trials."""
    client = embedded.create_lab("dashboard")
    ids = upload_inputs(client, clip.video)
    offered = httpx.get(_base(embedded) + "/openapi.json").json()["components"]["schemas"]["JobOptions"]
    artifacts = {name: True for name in ("overlay", "plots") if name in offered["properties"]}
    job = wait_for(client, submit(client, ids, marker_diameter_px=4.0, chunk_size=20, **artifacts)["id"])
    assert job["status"] == "succeeded", job
    trials = [{"video_ids": [ids["video_id"]]}] * 2
    batch = client.post("/batches", json={"model_id": ids["model_id"], "rig_id": ids["rig_id"],
                                          "trials": trials, "options": {"chunk_size": 20}}).json()
    for batch_job in batch["jobs"]:
        assert wait_for(client, batch_job["id"])["status"] == "succeeded"
    return client, {**ids, "job_id": job["id"], "batch_id": batch["id"]}


@pytest.fixture
def page(browser, embedded) -> Iterator:
    """A fresh tab (its own sessionStorage) on the dashboard; every URL it requested is recorded."""
    context = browser.new_context(accept_downloads=True)
    tab = context.new_page()
    tab.set_default_timeout(WAIT_MS)
    tab.requested, problems = [], []
    tab.on("request", lambda request: tab.requested.append(request.url))
    tab.on("pageerror", lambda error: problems.append(str(error)))
    tab.on("console", lambda message: problems.append(message.text) if "Refused" in message.text else None)
    tab.goto(_base(embedded) + "/")
    yield tab
    context.close()
    assert problems == []  # no script error, nothing the Content-Security-Policy had to refuse


def _base(deployment) -> str:
    return deployment.url.removesuffix("/v1")


def _key(client) -> str:
    return client.headers["Authorization"].removeprefix("Bearer ")


def _sign_in(page, key: str) -> None:
    page.get_by_label("Lab API key").fill(key)
    page.get_by_role("button", name="Sign in").click()
    page.locator("#lab").wait_for(state="visible")


def test_sign_in_and_see_a_running_jobs_progress_advance(page, embedded, lab, clip, tmp_path):
    client, ids = lab
    # Every image runs all its iterations (slow rig): a job that runs for some seconds.
    rig = client.post("/rigs", content=slow_rig(), headers={"Content-Type": "application/json"}).json()
    with repeated(clip.video, 2, tmp_path / "long.avi").open("rb") as f:
        video = client.post("/videos", files={"file": ("long.avi", f, "video/x-msvideo")}).json()
    job = submit(client, {**ids, "rig_id": rig["id"], "video_id": video["id"]},
                 marker_diameter_px=4.0, chunk_size=10, max_attempts=1)
    _sign_in(page, _key(client))

    row = page.locator(f"#job-row-{job['id']}")
    seen = []  # (status, images done, images total) as the page showed them
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120:
        bar = row.locator("progress")
        state = (row.get_attribute("data-status"), int(bar.get_attribute("value")),
                 int(bar.get_attribute("max")))
        if not seen or seen[-1] != state:
            seen.append(state)
        if state[0] in ("succeeded", "failed", "canceled"):
            break
        time.sleep(0.1)
    assert seen[-1] == ("succeeded", 80, 80), seen
    running = [done for status, done, total in seen if status in ("running", "reanalysing") and total == 80]
    assert running and min(running) < 80, seen  # the page showed the job unfinished …
    done = [d for _, d, _ in seen]
    assert done == sorted(done) and len(set(done)) >= 3, seen  # … and its progress advance
    # The key went in headers only: in no URL the page requested, and not in the server's log.
    key = _key(client)
    assert not [url for url in page.requested if key in url]
    assert key not in (Path(embedded.env["MOCAP_DATA_DIR"]) / "serve.log").read_text()


def test_a_finished_job_shows_its_plot_counts_artifacts_and_downloads(page, lab):
    client, ids = lab
    job_id = ids["job_id"]
    _sign_in(page, _key(client))
    page.get_by_role("link", name=f"Job {job_id}", exact=True).click()
    assert page.url.endswith(f"#job-{job_id}")
    page.get_by_role("heading", name=f"Job {job_id}: succeeded").wait_for()

    # Error over time, from angles.csv: one point per image (40 images, 40 pixel columns).
    points = page.locator("#error-plot polyline").get_attribute("points").split()
    assert len(points) == 40
    assert "40 images" in page.locator("#plot-desc").text_content()
    report = client.get(f"/jobs/{job_id}/report.json").json()
    shown = dict(page.locator("#job-counts tbody tr").evaluate_all(
        "rows => rows.map(r => [r.cells[0].textContent, Number(r.cells[1].textContent)])"))
    assert shown == {**report["status"], "re-analysed": report["reanalysed"],
                     "ambiguous": report["ambiguous"]}
    assert report["advice"] == [] and page.locator("#job-advice:visible").count() == 0
    assert report["ambiguous_dofs"] == {} and page.locator("#job-ambiguous:visible").count() == 0

    # Artifact images (angle plots, the overlay's contact sheet) load when the job has them.
    listed = client.get(f"/jobs/{job_id}/artifacts")
    names = listed.json() if listed.status_code == 200 else []
    for name, image in (("plots/angles.png", "#job-plots img[data-artifact='plots/angles.png']"),
                        ("overlay/contact_sheet.png", "#job-overlay-image")):
        if name in names:
            page.locator(image).wait_for(state="visible")
            assert page.locator(image).evaluate("img => img.decode().then(() => img.naturalWidth)") > 0
        else:
            assert page.locator(f"{image}:visible").count() == 0
    if "plots/angles.png" in names:  # a plot taller than its window (40rem) scrolls inside it
        window = page.locator("#job-plots .plot-window").first
        assert window.evaluate("w => w.clientHeight") <= 40 * 16
        assert window.evaluate("w => getComputedStyle(w).overflowY") == "auto"

    with page.expect_download() as download:
        page.get_by_role("link", name="angles.csv").click()
    assert download.value.suggested_filename == f"job-{job_id}-angles.csv"
    assert Path(download.value.path()).read_bytes() == client.get(f"/jobs/{job_id}/angles.csv").content


def test_a_job_mostly_over_the_threshold_shows_its_advice_and_ambiguous_dofs(page, lab):
    """report.json's advice (``core.pipeline.over_threshold_advice``) above the job's counts, and
    its ambiguous_dofs below them: a threshold no fit meets puts every image over it, and a
    claw joint that carries no marker leaves every image ambiguous in it."""
    client, ids = lab
    xml = (LOCUST / "model.xml").read_text().replace(
        "  <marker", '  <joint name="claw" parent="tarsus"><offset x="3"/>'
        '<dof axis="z" name="claw_z" min="-30" max="30"/></joint>\n  <marker', 1)
    model = client.post("/models", content=xml.encode(), headers={"Content-Type": "application/xml"})
    assert model.status_code == 201, model.text
    job = wait_for(client, submit(client, {**ids, "model_id": model.json()["id"]}, marker_diameter_px=4.0,
                                  chunk_size=20, max_attempts=1, error_threshold_px=0.001)["id"])
    report = client.get(f"/jobs/{job['id']}/report.json").json()
    (line,) = report["advice"]
    assert line.startswith("40 of 40 images are over the threshold")
    assert report["ambiguous_dofs"] == {"claw_z": 40}
    _sign_in(page, _key(client))
    page.get_by_role("link", name=f"Job {job['id']}", exact=True).click()
    page.get_by_role("heading", name=f"Job {job['id']}: succeeded").wait_for()
    shown = page.get_by_role("list", name="Advice on this job's fit")
    shown.wait_for(state="visible")
    assert shown.locator("li").all_text_contents() == report["advice"]
    assert page.locator("#job-ambiguous").text_content() == (
        "Ambiguous images by the DOF their alternative differs most in: claw_z 40.")


def test_batches_are_listed_with_their_jobs(page, lab):
    client, ids = lab
    _sign_in(page, _key(client))
    row = page.locator(f"#batch-row-{ids['batch_id']}")
    cells = [text.strip() for text in row.locator("td").all_text_contents()]
    assert cells[:3] == ["succeeded", "2 succeeded", "80 / 80 images"]
    assert row.get_by_role("link", name="archive.zip").is_visible()
    trials = page.locator("#jobs tbody tr", has_text=f"batch {ids['batch_id']}, trial")
    assert trials.count() == 2


def test_uploads_are_listed_with_their_metadata(page, lab, clip):
    client, ids = lab
    _sign_in(page, _key(client))
    video = page.locator("#videos tbody tr", has_text=f"Video {ids['video_id']}")
    video.wait_for()
    cells = video.locator("td").all_text_contents()
    assert cells[:4] == [clip.video.name, "40", "50", "720 × 576"]
    assert page.locator("#models tbody tr", has_text=f"Model {ids['model_id']}").locator("td").nth(0) \
        .text_content() == "locust_hind_leg"
    assert page.locator("#rigs tbody tr", has_text=f"Rig {ids['rig_id']}").count() == 1


def test_another_labs_key_sees_none_of_it(page, embedded, lab):
    _, ids = lab
    other = embedded.create_lab("dashboard-other")
    _sign_in(page, _key(other))
    page.locator("#jobs-empty").wait_for(state="visible")
    assert page.locator("#jobs tbody tr").count() == 0
    assert page.locator("#videos tbody tr").count() == 0
    page.evaluate(f"location.hash = '#job-{ids['job_id']}'")
    problem = page.locator("#job-problem")
    problem.wait_for(state="visible")
    assert problem.text_content() == f"Job {ids['job_id']} does not exist or belongs to another lab."
    assert page.locator("#job-body").is_hidden()


def test_a_wrong_key_is_refused_and_forgotten(page):
    page.get_by_label("Lab API key").fill("not-a-key")
    page.get_by_role("button", name="Sign in").click()
    page.get_by_role("alert").filter(has_text="not accepted").wait_for()
    assert page.evaluate("sessionStorage.length") == 0
    assert page.locator("#lab").is_hidden()


@pytest.mark.parametrize("path", ["/docs", "/redoc"])
def test_api_docs_render_every_operation_with_other_hosts_unreachable(browser, embedded, path):
    base = _base(embedded)
    server = urlsplit(base).netloc
    operations = [(method, route) for route, item in
                  httpx.get(base + "/openapi.json").json()["paths"].items() for method in item]
    context = browser.new_context()
    elsewhere = []

    def only_this_server(route) -> None:
        if urlsplit(route.request.url).netloc == server:
            route.continue_()
        else:
            elsewhere.append(route.request.url)
            route.abort("internetdisconnected")

    context.route("**/*", only_this_server)
    tab = context.new_page()
    tab.set_default_timeout(WAIT_MS)
    tab.goto(base + path)
    if path == "/docs":
        blocks = tab.locator(".opblock")
        blocks.nth(len(operations) - 1).wait_for()
        assert blocks.count() == len(operations)
        job_path = re.compile(r"^/v1/jobs/\{job_id\}$")
        assert tab.locator(".opblock-summary-path", has_text=job_path).count() == 1
    else:
        tab.get_by_role("heading", name="Submit a job; poll the Location it returns").wait_for()
        tab.locator("[data-section-id^='operation/']").nth(len(operations) - 1).wait_for(state="attached")
        assert tab.locator("[data-section-id^='operation/']").count() == len(operations)
    tab.wait_for_load_state("networkidle")
    context.close()
    assert elsewhere == []


def test_the_dashboard_loads_nothing_from_elsewhere(page, embedded):
    headers = httpx.get(_base(embedded) + "/").headers
    assert headers["Content-Security-Policy"].startswith("default-src 'self'")
    page.wait_for_load_state("networkidle")
    server = urlsplit(_base(embedded)).netloc
    assert {urlsplit(url).netloc for url in page.requested} == {server}
    assert page.get_by_role("heading", name="mocap lab dashboard").is_visible()

