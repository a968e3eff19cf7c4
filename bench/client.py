"""The Python client's own cost: CPU seconds to upload a video through ``service.client`` (with a
progress callback, as ``mocap remote upload`` runs it) against a plain httpx multipart post of the
same file, and to check that an archive on disk is complete (the test a resumed download makes).

Needs a running service and a lab's key (``mocap serve``; ``mocap admin create-lab``):

    python bench/client.py VIDEO --url http://127.0.0.1:8000 --key-file KEY [--runs 3]

CPU time of this process only (time.process_time): the server's work is not counted.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import httpx

# The repository first: run as a script, bench/ leads sys.path and bench/service.py would be "service".
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from service.client import Client, archive_complete, load_key


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("video", type=Path)
    parser.add_argument("--url", default="http://127.0.0.1:8000")
    parser.add_argument("--key-file", type=Path, required=True)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    key, size = load_key(args.key_file), args.video.stat().st_size
    with Client(args.url, key, timeout=300) as api, httpx.Client(
            base_url=api.url, timeout=300, headers={"Authorization": f"Bearer {key}"}) as raw:
        for run in range(args.runs):
            calls: list[int] = []
            t = time.process_time()
            api.upload_video(args.video, progress=calls.append)
            ours = time.process_time() - t
            t = time.process_time()
            with args.video.open("rb") as f:
                raw.post("/videos", files={"file": (args.video.name, f, "application/octet-stream")}
                         ).raise_for_status()
            plain = time.process_time() - t
            print(f"run {run}: {size / 1e6:.1f} MB; service.client {ours:.3f} CPU s "
                  f"({len(calls)} progress calls), plain httpx {plain:.3f} CPU s")
    with tempfile.TemporaryDirectory() as tmp:
        archive = Path(tmp) / "a.zip"
        with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as z:
            z.write(args.video, "overlay.avi")
        t = time.process_time()
        whole = archive_complete(archive)
        print(f"complete-archive check (every CRC-32) of a {archive.stat().st_size / 1e6:.1f} MB zip: "
              f"{whole}, {time.process_time() - t:.3f} CPU s")


if __name__ == "__main__":
    main()
