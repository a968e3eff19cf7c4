"""The API's HTTP server: uvicorn with limits on slow and numerous clients.

uvicorn times out only a connection left idle after a response (``timeout_keep_alive``);
one that opens and sends its headers a byte at a time (slow-loris) would be held for ever,
and its httptools parser buffers a header of any size (a 66 MB header line grew the API by
106 MB). :class:`HeaderTimeoutProtocol` closes a connection whose request line and headers
have not all arrived ``MOCAP_HEADER_TIMEOUT_S`` after it opened or after the request's first
byte, and answers 431 once they pass :data:`MAX_HEADER_BYTES`; bodies are bounded by
``service.api.guard``. ``MOCAP_MAX_CONNECTIONS`` caps open connections
(uvicorn answers 503 beyond). ``mocap serve`` runs this; ``python -m service.api.server
--port N`` runs the API alone.
"""

from __future__ import annotations

import argparse
import asyncio

import uvicorn
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from service.api.app import create_app
from service.settings import get_settings

KEEP_ALIVE_S = 5  # an idle connection between requests (uvicorn's default, stated)
# A request's line and headers (clients send a few hundred bytes; browsers < 8 KiB). Counted
# from the read after the one that began them, so memory holds at most this plus two reads.
MAX_HEADER_BYTES = 64 * 1024


class HeaderTimeoutProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a deadline on each request's line and headers."""

    _header_timer: asyncio.TimerHandle | None = None
    _header_bytes = 0

    # uvicorn's own connection_made narrows asyncio's BaseTransport to Transport (and ignores it alike).
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm()

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._arm()

    def data_received(self, data: bytes) -> None:
        heading = self._header_timer is not None  # mid-headers before this read
        super().data_received(data)
        if heading and self._header_timer is not None:
            self._header_bytes += len(data)
            if self._header_bytes > MAX_HEADER_BYTES and not self.transport.is_closing():
                self._disarm()
                self.transport.write(b"HTTP/1.1 431 Request Header Fields Too Large\r\n"
                                     b"content-length: 0\r\nconnection: close\r\n\r\n")
                self.transport.close()

    def on_headers_complete(self) -> None:
        self._disarm()
        super().on_headers_complete()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def _arm(self) -> None:
        self._disarm()
        self._header_bytes = 0
        self._header_timer = self.loop.call_later(get_settings().header_timeout_s, self._expire)

    def _disarm(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _expire(self) -> None:
        self._header_timer = None
        if not self.transport.is_closing():
            self.logger.info("closed a connection whose request headers did not arrive in time")
            self.transport.close()


def serve(host: str, port: int, log_level: str = "info") -> None:
    """Run the API until interrupted."""
    uvicorn.run(create_app(), host=host, port=port, log_level=log_level, http=HeaderTimeoutProtocol,
                timeout_keep_alive=KEEP_ALIVE_S, limit_concurrency=get_settings().max_connections)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="The mocap API alone (no workers, no reaper).")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--log-level", default="info")
    arguments = parser.parse_args()
    serve(arguments.host, arguments.port, arguments.log_level)
