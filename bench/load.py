"""Load test: 100 short trials uploaded, submitted and polled by 10 concurrent clients, then every
result checked complete; throughput, p50/p99 latency per endpoint, status codes, errors.

Starts its own API (uvicorn) and ``mocap worker`` on PostgreSQL and Redis on 127.0.0.1 (a
schema and a queue of its own), or with ``--embedded`` on SQLite and the filesystem broker.
Each client owns an equal share of the trials and, for each, uploads the video, submits a
job, polls its status until it ends, then downloads angles.csv and checks it has a row for
every image, in order, none without a status.

    python bench/load.py [--trials 100] [--clients 10] [--images 20] [--workers 2] [--embedded]

Targets: zero lost (every job succeeded, every angles.csv complete), zero 5xx.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import importlib.util
import io
import time
from collections import Counter, defaultdict
from pathlib import Path
from tempfile import TemporaryDirectory

import httpx
import numpy as np
from sqlalchemy import create_engine, text

from core.examples import LOCUST

# bench/service.py's helpers (render, start the API and workers, create a lab), loaded by path:
# run as a script, bench/ comes first on sys.path and "service" would be that file anyway.
_spec = importlib.util.spec_from_file_location("bench_service", Path(__file__).with_name("service.py"))
assert _spec is not None and _spec.loader is not None
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

TERMINAL = {"succeeded", "failed", "canceled"}
# A Redis db of its own: the fault tests FLUSHDB db 10 (bench/service.py's), which once dropped
# three of this script's queued chunks when both ran at the same time.
REDIS_URL = "redis://127.0.0.1:6379/11"
OPTIONS = {"marker_diameter_px": 4.0, "chunk_size": 50, "max_attempts": 2}


class Recorder:
    """Latency (ms) and status code of every request, by endpoint (the path with ids as {id})."""

    def __init__(self) -> None:
        self.latencies: dict[str, list[float]] = defaultdict(list)
        self.codes: Counter[tuple[str, int]] = Counter()

    async def request(self, client: httpx.AsyncClient, endpoint: str, method: str, url: str,
                      **kwargs) -> httpx.Response:
        t0 = time.perf_counter()
        response = await client.request(method, url, **kwargs)
        self.latencies[endpoint].append((time.perf_counter() - t0) * 1000)
        self.codes[(endpoint, response.status_code)] += 1
        return response


def complete(angles: str, images: int) -> bool:
    """An angles.csv with one row per image, samples 0..images-1 in order, each with a status."""
    rows = list(csv.reader(io.StringIO(angles)))[1:]
    return [int(r[0]) for r in rows] == list(range(images)) and all(r[-1] for r in rows)


async def trial(client: httpx.AsyncClient, rec: Recorder, video: Path, ids: dict[str, int],
                images: int, poll_s: float, timeout_s: float) -> str:
    """One trial from upload to checked result: 'complete' or what went wrong."""
    uploaded = await rec.request(client, "POST /videos", "POST", "/videos",
                                 files={"file": (video.name, video.read_bytes(), "video/x-msvideo")})
    if uploaded.status_code != 201:
        return f"upload {uploaded.status_code}"
    body = {**ids, "video_ids": [uploaded.json()["id"]], "options": OPTIONS}
    submitted = await rec.request(client, "POST /jobs", "POST", "/jobs", json=body)
    if submitted.status_code != 202:
        return f"submit {submitted.status_code}"
    job_id, deadline = submitted.json()["id"], time.monotonic() + timeout_s
    while True:
        await asyncio.sleep(poll_s)
        polled = await rec.request(client, "GET /jobs/{id}", "GET", f"/jobs/{job_id}")
        if polled.status_code == 200 and polled.json()["status"] in TERMINAL:
            break
        if time.monotonic() > deadline:
            return f"lost: still {polled.json()['status']} after {timeout_s:.0f} s"
    if polled.json()["status"] != "succeeded":
        return f"job {polled.json()['status']}: {polled.json()['error']}"
    angles = await rec.request(client, "GET /jobs/{id}/angles.csv", "GET", f"/jobs/{job_id}/angles.csv")
    return "complete" if angles.status_code == 200 and complete(angles.text, images) else "incomplete"


async def run_clients(url: str, key: str, videos: list[Path], ids: dict[str, int], trials: int,
                      clients: int, images: int, poll_s: float,
                      timeout_s: float) -> tuple[Recorder, Counter[str]]:
    rec, outcomes = Recorder(), Counter[str]()
    async with httpx.AsyncClient(base_url=url, headers={"Authorization": key}, timeout=120) as client:
        async def one_client(c: int) -> None:
            for t in range(c, trials, clients):  # client c: trials c, c + clients, …
                video = videos[t % len(videos)]
                outcomes[await trial(client, rec, video, ids, images, poll_s, timeout_s)] += 1
        await asyncio.gather(*(one_client(c) for c in range(clients)))
    return rec, outcomes


def report(rec: Recorder, outcomes: Counter[str], seconds: float, trials: int, images: int,
           uploaded_mb: float) -> None:
    print(f"{trials} trials ({trials * images} images, {uploaded_mb:.0f} MB uploaded) in {seconds:.1f} s: "
          f"{trials / seconds:.2f} trials/s, {trials * images / seconds:.0f} images/s")
    print(f"{'endpoint':<28}{'requests':>9}{'p50 ms':>9}{'p99 ms':>9}  status codes")
    for endpoint, values in rec.latencies.items():
        p50, p99 = np.percentile(values, [50, 99])
        codes = {code: n for (e, code), n in sorted(rec.codes.items()) if e == endpoint}
        print(f"{endpoint:<28}{len(values):>9}{p50:>9.1f}{p99:>9.1f}  {codes}")
    server_errors = sum(n for (_, code), n in rec.codes.items() if code >= 500)
    lost = trials - outcomes["complete"]
    print(f"outcomes: {dict(outcomes)}; lost or incomplete: {lost} (target 0); 5xx: {server_errors} "
          "(target 0)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--clients", type=int, default=10)
    parser.add_argument("--images", type=int, default=20, help="images per trial")
    parser.add_argument("--distinct", type=int, default=10, help="distinct rendered trials (reused)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--poll-interval", type=float, default=0.5)
    parser.add_argument("--job-timeout", type=float, default=300.0,
                        help="seconds after submission a job still not ended counts as lost")
    parser.add_argument("--embedded", action="store_true")
    args = parser.parse_args()
    with TemporaryDirectory() as tmp:
        data = Path(tmp)
        videos = bench.render_trials(data, args.distinct, args.images)
        env, schema = bench.environment(data / "service", args.embedded)
        if schema:
            env["MOCAP_BROKER_URL"] = REDIS_URL
        port = bench.free_port()
        url = f"http://127.0.0.1:{port}/v1"
        api = bench.start_api(env, port, data / "api.log")
        workers = bench.start_workers(env, args.workers, data / "workers.log")
        try:
            lab = bench.create_lab(env, url)
            model = lab.post("/models", content=(LOCUST / "model.xml").read_bytes()).json()["id"]
            rig = lab.post("/rigs", content=(LOCUST / "rig.json").read_bytes()).json()["id"]
            t0 = time.perf_counter()
            rec, outcomes = asyncio.run(run_clients(
                url, lab.headers["Authorization"], videos, {"model_id": model, "rig_id": rig},
                args.trials, args.clients, args.images, args.poll_interval, args.job_timeout))
            seconds = time.perf_counter() - t0
            sizes = [videos[t % len(videos)].stat().st_size for t in range(args.trials)]
            report(rec, outcomes, seconds, args.trials, args.images, sum(sizes) / 1e6)
        finally:
            bench.stop(workers)
            bench.stop(api)
            if schema:
                with create_engine(bench.PG).begin() as conn:
                    conn.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))


if __name__ == "__main__":
    main()
