"""Local storage: atomic writes, keys that cannot escape the root."""

from __future__ import annotations

import pytest

from service.storage import LocalStorage


def test_put_then_open_round_trips(tmp_path):
    storage = LocalStorage(tmp_path)
    assert storage.put("jobs/1/angles.csv", [b"a,b\n", b"1,2\n"]) == 8
    with storage.open("jobs/1/angles.csv") as f:
        assert f.read() == b"a,b\n1,2\n"
    assert storage.exists("jobs/1/angles.csv")
    storage.delete("jobs/1/angles.csv")
    assert not storage.exists("jobs/1/angles.csv")


def test_a_failed_write_leaves_no_file_and_no_partial(tmp_path):
    storage = LocalStorage(tmp_path)

    def chunks():
        yield b"half a video"
        raise ConnectionError("client went away")

    with pytest.raises(ConnectionError):
        storage.put("videos/abc", chunks())
    assert not storage.exists("videos/abc")
    assert list((tmp_path / "videos").iterdir()) == []


def test_a_failed_rewrite_keeps_the_previous_file(tmp_path):
    storage = LocalStorage(tmp_path)
    storage.put("k", [b"old"])
    with pytest.raises(RuntimeError), storage.writer("k") as f:
        f.write(b"new but incomplete")
        raise RuntimeError
    assert storage.path("k").read_bytes() == b"old"


@pytest.mark.parametrize("key", ["../etc/passwd", "/abs", "a/../../b", "a b", "", "a//b", "videos/x\0y"])
def test_keys_that_could_escape_or_confuse_are_refused(tmp_path, key):
    with pytest.raises(ValueError, match="invalid storage key"):
        LocalStorage(tmp_path).path(key)
