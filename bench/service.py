"""Service benchmark: 20 trials as one batch through the API, with 1 and 2 worker processes,
and status-poll latency under 50 concurrent pollers while the workers are busy.

Runs real processes on this machine: uvicorn (the API) and ``mocap worker``, on PostgreSQL
and Redis on 127.0.0.1 (a schema and a queue of its own), or with ``--embedded`` on SQLite
and the filesystem broker (``mocap serve``'s defaults).

    python bench/service.py [--trials 20] [--images 150] [--embedded]

Targets: 2 workers >= 1.8x faster than 1; poll p99 < 50 ms. (This script imports no
``service`` module: run as a file, its own name would shadow the package.)
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import numpy as np
from sqlalchemy import create_engine, text

from core.examples import LOCUST
from core.model import KinematicModel
from core.rig import Rig
from core.synth import natural_movements, render_frames, write_video

PG = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
OPTIONS = {"marker_diameter_px": 4.0, "chunk_size": 50, "histogram_version": 1}


def render_trials(folder: Path, trials: int, images: int) -> list[Path]:
    model = KinematicModel.from_xml(LOCUST / "model.xml")
    rig = Rig.from_json(LOCUST / "rig.json")
    paths = []
    for k in range(trials):
        rng = np.random.default_rng(1000 + k)
        truth = natural_movements(model, rig, images, rng=rng, n_sequences=2)
        paths.append(folder / f"trial{k:02d}.avi")
        write_video(paths[-1], render_frames(model, rig, truth, rng=rng, marker_diameter_px=4.0), fps=50.0)
    return paths


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# Redis db 12: tests use 9 and 10 (which the fault tests flush), bench/load.py 11.
REDIS_URL = "redis://127.0.0.1:6379/12"


def environment(data: Path, embedded: bool) -> tuple[dict[str, str], str | None]:
    env = dict(os.environ, MOCAP_DATA_DIR=str(data), PYTHONUNBUFFERED="1")
    if embedded:
        return env, None
    schema = f"mocap_bench_{uuid.uuid4().hex[:8]}"
    with create_engine(PG).begin() as conn:
        conn.execute(text(f'CREATE SCHEMA "{schema}"'))
    env.update(MOCAP_DATABASE_URL=f"{PG}?options=-csearch_path%3D{schema}",
               MOCAP_BROKER_URL=REDIS_URL, MOCAP_QUEUE=f"bench-{schema}")
    return env, schema


def start_api(env: dict[str, str], port: int, log: Path) -> subprocess.Popen:
    subprocess.run([sys.executable, "-m", "service.migrate"], env=env, check=True, capture_output=True)
    api = subprocess.Popen([sys.executable, "-m", "service.api.server", "--port", str(port),
                            "--log-level", "warning"],
                           env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)
    for _ in range(300):
        try:
            if httpx.get(f"http://127.0.0.1:{port}/openapi.json").status_code == 200:
                return api
        except httpx.HTTPError:
            time.sleep(0.1)
    raise RuntimeError("API did not start")


def start_workers(env: dict[str, str], n: int, log: Path) -> subprocess.Popen:
    # --nice 10, as `mocap serve` runs its workers: on one machine the API must not wait for CPU
    # behind fitting processes (in docker-compose they are separate containers).
    worker = subprocess.Popen([sys.executable, "-m", "service.cli", "worker", "--concurrency", str(n),
                               "--nice", "10"],
                              env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)
    time.sleep(4.0)  # the pool is up and numba's cache loaded before the clock starts
    return worker


def stop(process: subprocess.Popen) -> None:
    process.terminate()
    process.wait(timeout=60)


def create_lab(env: dict[str, str], url: str) -> httpx.Client:
    out = subprocess.run([sys.executable, "-m", "service.cli", "admin", "create-lab", "bench"],
                         env=env, capture_output=True, text=True, check=True).stdout
    key = out.strip().splitlines()[-1]
    return httpx.Client(base_url=url, headers={"Authorization": f"Bearer {key}"}, timeout=60)


def upload(client: httpx.Client, videos: list[Path]) -> dict:
    model = client.post("/models", content=(LOCUST / "model.xml").read_bytes()).json()["id"]
    rig = client.post("/rigs", content=(LOCUST / "rig.json").read_bytes()).json()["id"]
    ids = []
    for path in videos:
        with path.open("rb") as f:
            ids.append(client.post("/videos", files={"file": (path.name, f)}).json()["id"])
    return {"model_id": model, "rig_id": rig, "trials": [{"video_ids": [v]} for v in ids],
            "options": OPTIONS}


def busy_cpu_seconds() -> float:
    """CPU seconds every process of the machine has used (``/proc/stat``): tells whether something
    besides this benchmark was using the cores while it measured."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = fields[3] + fields[4]
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def tree_cpu_seconds(pid: int) -> float:
    """CPU seconds used so far by process ``pid`` and its children (the Celery pool)."""
    total, tick = 0.0, os.sysconf("SC_CLK_TCK")
    pids = [pid, *(int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split())]
    for p in pids:
        fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    return total


def run_batch(client: httpx.Client, body: dict) -> tuple[float, int]:
    """Seconds from submission to every job succeeded; the batch id."""
    t0 = time.perf_counter()
    batch = client.post("/batches", json=body).json()["id"]
    while (state := client.get(f"/batches/{batch}").json())["status"] == "running":
        time.sleep(0.25)  # polling must not take CPU from the workers it is timing
    if state["status"] != "succeeded":
        raise RuntimeError(f"batch {batch} ended {state['statuses']}")
    return time.perf_counter() - t0, batch


async def poll_latencies(url: str, key: str, job_ids: list[int], pollers: int, seconds: float,
                         interval: float) -> list[float]:
    """``pollers`` concurrent clients, each polling a job's status every ``interval`` seconds (0: as
    fast as it can) for ``seconds``: every latency, in ms."""
    latencies: list[float] = []
    limits = httpx.Limits(max_connections=pollers)
    async with httpx.AsyncClient(base_url=url, headers={"Authorization": key}, limits=limits) as client:
        async def poller(k: int) -> None:
            end = time.perf_counter() + seconds
            await asyncio.sleep(interval * k / pollers)  # pollers spread over the interval
            while time.perf_counter() < end:
                t0 = time.perf_counter()
                response = await client.get(f"/jobs/{job_ids[k % len(job_ids)]}")
                latencies.append((time.perf_counter() - t0) * 1000)
                response.raise_for_status()
                await asyncio.sleep(max(0.0, interval - (time.perf_counter() - t0)))
        await asyncio.gather(*(poller(k) for k in range(pollers)))
    return latencies


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--images", type=int, default=150)
    parser.add_argument("--pollers", type=int, default=50)
    parser.add_argument("--poll-interval", type=float, default=1.0,
                        help="seconds between one poller's requests (0: back to back)")
    parser.add_argument("--embedded", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp)
        t0 = time.perf_counter()
        videos = render_trials(data, args.trials, args.images)
        print(f"rendered {args.trials} trials of {args.images} images in {time.perf_counter() - t0:.1f} s")
        env, schema = environment(data / "service", args.embedded)
        port = free_port()
        url = f"http://127.0.0.1:{port}/v1"
        api = start_api(env, port, data / "api.log")
        try:
            client = create_lab(env, url)
            body = upload(client, videos)
            seconds = {}
            for n in (1, 2):
                workers = start_workers(env, n, data / f"workers{n}.log")
                cpu, own = busy_cpu_seconds(), tree_cpu_seconds(workers.pid)
                seconds[n], _ = run_batch(client, body)
                cores = (busy_cpu_seconds() - cpu) / seconds[n]
                worker_cores = (tree_cpu_seconds(workers.pid) - own) / seconds[n]
                stop(workers)
                images = args.trials * args.images
                print(f"{n} worker(s): {args.trials} trials, {images} images: all succeeded in "
                      f"{seconds[n]:.2f} s ({images / seconds[n]:.0f} images/s); the machine's "
                      f"{os.cpu_count()} cores were busy {cores:.2f} on average, the workers "
                      f"{worker_cores:.2f}")
            print(f"speed-up 2 vs 1 workers: {seconds[1] / seconds[2]:.2f}x (target >= 1.8x)")

            workers = start_workers(env, 2, data / "workers-poll.log")
            batch = client.post("/batches", json=body).json()
            ids = [j["id"] for j in batch["jobs"]]
            busy = min(seconds[2] * 0.8, 20.0)
            latencies = asyncio.run(poll_latencies(url, client.headers["Authorization"], ids,
                                                   args.pollers, busy, args.poll_interval))
            active = client.get(f"/batches/{batch['id']}").json()["status"]
            stop(workers)
            p50, p99 = np.percentile(latencies, [50, 99])
            print(f"status polls, {args.pollers} concurrent pollers (one request per {args.poll_interval} s "
                  f"each) for {busy:.1f} s while 2 workers fit "
                  f"(batch still {active}): {len(latencies)} requests, p50 {p50:.1f} ms, p99 {p99:.1f} ms "
                  f"(target p99 < 50 ms)")
        finally:
            stop(api)
            if schema:
                with create_engine(PG).begin() as conn:
                    conn.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))


if __name__ == "__main__":
    main()
