"""Documents sent multipart without a Content-Length are read no further than the limit.

Starlette's form parser spools file fields to disk without bound; service.upload reads the
body itself first. Driven through a real starlette Request fed by an ASGI receive that
counts what the reader pulled.
"""

from __future__ import annotations

import asyncio

import pytest
from starlette.requests import Request

from service.upload import MULTIPART_SLACK, TooLargeError, read_document, read_documents

BLOCK = 64 * 1024
LIMIT = 2**20


def _request(total: int) -> tuple[Request, list[int]]:
    """A chunked multipart request of ``total`` bytes of file data; the list counts bytes pulled."""
    boundary = "b0undary"
    head = (f"--{boundary}\r\n"
            'Content-Disposition: form-data; name="file"; filename="big.toml"\r\n\r\n').encode()
    pulled = [0]

    async def receive() -> dict:
        sent = pulled[0]
        if sent == 0:
            chunk = head
        elif sent - len(head) < total:
            chunk = b"#" * BLOCK
        else:
            return {"type": "http.request", "body": f"\r\n--{boundary}--\r\n".encode(), "more_body": False}
        pulled[0] += len(chunk)
        return {"type": "http.request", "body": chunk, "more_body": True}

    scope = {"type": "http", "method": "POST", "path": "/", "query_string": b"",
             "headers": [(b"content-type", f"multipart/form-data; boundary={boundary}".encode())]}
    return Request(scope, receive), pulled


@pytest.mark.parametrize("read", [lambda r: read_document(r, LIMIT), lambda r: read_documents(r, LIMIT, 16)])
def test_a_chunked_body_is_not_read_past_the_limit(read):
    request, pulled = _request(total=1024 * 2**20)  # 1 GiB offered
    with pytest.raises(TooLargeError):
        asyncio.run(read(request))
    assert pulled[0] <= LIMIT + MULTIPART_SLACK + BLOCK


def test_a_small_chunked_body_is_read_whole():
    request, _ = _request(total=3 * BLOCK)
    [(name, data)] = asyncio.run(read_documents(request, LIMIT, 16))
    assert name == "big.toml" and data == b"#" * 3 * BLOCK
