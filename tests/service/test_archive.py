"""Zip archives streamed piece by piece read back whole."""

from __future__ import annotations

import io
import zipfile

from service.archive import stream_zip
from service.storage import LocalStorage


def test_streamed_zip_holds_stored_files_and_small_entries(tmp_path):
    storage = LocalStorage(tmp_path)
    big = bytes(range(256)) * 20_000  # 5 MB: several blocks
    storage.put("jobs/1/angles.csv", [big])
    pieces = list(stream_zip([("a/angles.csv", storage, "jobs/1/angles.csv"), ("a/rig.json", b"{}\n")]))
    assert len(pieces) > 2  # written as it goes, not in one piece at the end
    archive = zipfile.ZipFile(io.BytesIO(b"".join(pieces)))
    assert archive.testzip() is None
    assert archive.read("a/angles.csv") == big
    assert archive.read("a/rig.json") == b"{}\n"
    assert archive.getinfo("a/rig.json").date_time[0] >= 2024
