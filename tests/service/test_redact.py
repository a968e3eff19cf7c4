"""Messages name a stored video as the lab uploaded it, whatever form of its location they hold."""

from __future__ import annotations

from pathlib import Path

from service.models import Video
from service.redact import redact, video_names

ROOT = Path("/srv/mocap-data/storage")


def test_a_videos_path_key_and_file_name_become_its_id_and_upload_name():
    video = Video(id=12, storage_key="videos/3f2a", filename="trial 1.avi")
    names = video_names([video], ROOT)
    label = "video 12 ('trial 1.avi')"
    for form in (f"{ROOT}/videos/3f2a", "videos/3f2a", "3f2a"):
        assert redact(f"{form}: ended at frame 7", names, ROOT) == f"{label}: ended at frame 7"


def test_any_other_stored_path_becomes_a_stored_file():
    message = f"[Errno 2] No such file or directory: '{ROOT}/jobs/4/merged.npz'"
    assert redact(message, {}, ROOT) == "[Errno 2] No such file or directory: 'a stored file'"
