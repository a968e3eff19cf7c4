"""The embedded service's broker: a message appears in the queue folder only whole."""

from __future__ import annotations

import json
import os

from kombu import Connection

from service.broker import make_celery
from service.settings import Settings


def test_a_message_is_written_whole_before_it_appears_in_the_queue(tmp_path, monkeypatch):
    """kombu's own filesystem transport creates the file in the queue folder and then writes
    it, and a consumer could read it empty (its worker then stopped for good). Here the queue
    folder never holds a file until it is complete."""
    app = make_celery(Settings(data_dir=tmp_path, broker_url="filesystem://"))
    options = app.conf.broker_transport_options
    queue, incoming = options["data_folder_in"], options["incoming_folder"]
    moves = []
    replace = os.replace

    def watched(src: str, dst: str) -> None:
        assert not os.listdir(queue)  # nothing of the message in the queue yet
        with open(src) as f:
            moves.append(json.load(f))  # complete before it is moved
        replace(src, dst)

    monkeypatch.setattr(os, "replace", watched)
    with Connection(app.conf.broker_url, transport=app.conf.broker_transport,
                    transport_options=options) as connection:
        channel = connection.default_channel
        channel._put("jobs", {"body": "one"})
        assert moves == [{"body": "one"}]
        assert not os.listdir(incoming) and len(os.listdir(queue)) == 1
        assert channel._get("jobs") == {"body": "one"}
    assert not os.listdir(queue)
