"""Messages shown to labs name what they uploaded, never the server's paths or storage keys.

``core`` names a video by its path (``/srv/…/storage/videos/3f…: not a video file FFmpeg
can decode``): right for ``mocap fit``, where the user gave that path, wrong for the
service, where the path is the server's and the name a storage key. :func:`redact` puts
the video's id and upload name in its place, and any other path under the storage folder
becomes "a stored file".
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from pathlib import Path, PurePosixPath

from service.models import Video


def video_label(video: Video) -> str:
    """How messages name an uploaded video: ``video 12 ('trial1_cam0.avi')``."""
    return f"video {video.id} ({video.filename!r})"


def stored_names(key: str, path: Path, label: str) -> dict[str, str]:
    """The forms a stored file takes in messages (its path, key and file name), each to ``label``."""
    return {str(path): label, key: label, PurePosixPath(key).name: label}


def video_names(videos: Iterable[Video], storage_root: Path) -> dict[str, str]:
    """:func:`stored_names` of every video in ``videos``."""
    return {form: label for v in videos
            for form, label in stored_names(v.storage_key, storage_root / v.storage_key,
                                            video_label(v)).items()}


def redact(message: str, names: Mapping[str, str], storage_root: Path) -> str:
    """``message`` with every form in ``names`` replaced by its label (longest forms first, so
    a path goes before the key it ends with), then any other path under ``storage_root``."""
    for form in sorted(names, key=len, reverse=True):
        message = message.replace(form, names[form])
    return re.sub(re.escape(str(storage_root)) + r"/[^\s'\":,]*", "a stored file", message)
