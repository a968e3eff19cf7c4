"""kombu's filesystem transport, each message written whole before it appears in the queue.

kombu's filesystem transport (5.x) creates a message's file in the queue folder, then locks
it and writes it; a consumer lists the folder, moves the file away and reads it without the
lock, so it can read the file still empty. The worker's consumer then stops on a
``JSONDecodeError`` ("Unrecoverable error") and every job of the embedded service stays
queued (kombu issue #1551; seen in this repository's CI on 2026-11-30: a job queued for
120 s). Here a message is written in full in the transport option ``incoming_folder``, on
the queue folder's filesystem, and moved into the queue in one ``os.replace``, which is
atomic there.
"""

from __future__ import annotations

import os
import uuid
from time import monotonic
from typing import Any

from kombu.exceptions import ChannelError
from kombu.transport import filesystem
from kombu.utils.encoding import str_to_bytes
from kombu.utils.json import dumps

__all__ = ["Transport"]


class Channel(filesystem.Channel):
    def _put(self, queue: Any, message: Any, **kwargs: Any) -> None:  # type: ignore[override]
        """Put ``message`` onto ``queue`` under the name kombu's reader looks for, written in
        ``incoming_folder`` first, then moved into the queue folder whole."""
        name = f"{round(monotonic() * 1000)}_{uuid.uuid4()}.{queue}.msg"
        staged = os.path.join(self.transport_options["incoming_folder"], name)
        try:
            with open(staged, "wb") as f:
                f.write(str_to_bytes(dumps(message)))  # type: ignore[no-untyped-call]
            os.replace(staged, os.path.join(self.data_folder_out, name))
        except OSError as exc:
            raise ChannelError(f"Cannot add file {name!r} to the queue") from exc


class Transport(filesystem.Transport):
    Channel = Channel
