"""The Foxglove view's front door: both WebSocket subprotocols of the Foxglove protocol.

foxglove-sdk's server negotiates only ``foxglove.sdk.v1``, the current name of the Foxglove
WebSocket protocol; the open-source Foxglove-compatible viewers (and older Foxglove apps) offer
``foxglove.websocket.v1``, the same protocol under its first name, and the SDK answers them
HTTP 400. This bridge listens where the view was configured, reads each client's opening
handshake (bounded in size and time), offers the SDK the name it knows in place of the old one,
gives the client back the name it asked for, and then copies bytes both ways untouched: after
the handshake the two subprotocols exchange the same frames.

It runs in a thread of its own with its own asyncio loop, never on the RT path; a client that
sends garbage, too much, or nothing loses its connection and nothing else.
"""

from __future__ import annotations

import asyncio
import logging
import re
import threading

log = logging.getLogger(__name__)

OLD = b"foxglove.websocket.v1"
NEW = b"foxglove.sdk.v1"
MAX_HEADER_BYTES = 16 * 1024  # an opening handshake is a few hundred bytes
HANDSHAKE_TIMEOUT_S = 5.0
CHUNK = 64 * 1024
PROTOCOL_HEADER = re.compile(rb"^(sec-websocket-protocol:[ \t]*)(.*?)\r$", re.IGNORECASE | re.MULTILINE)


def _rewrite_offer(header: bytes) -> tuple[bytes, bool]:
    """The request header with ``foxglove.websocket.v1`` offered as ``foxglove.sdk.v1``; True when
    the client offered only the old name (its answer must carry the old name back)."""
    match = PROTOCOL_HEADER.search(header)
    if match is None:
        return header, False
    offered = [p.strip() for p in match.group(2).split(b",")]
    if NEW in offered or OLD not in offered:
        return header, False
    new_value = b", ".join(NEW if p == OLD else p for p in offered)
    return header[:match.start(2)] + new_value + header[match.end(2):], True


def _rewrite_answer(header: bytes) -> bytes:
    """The SDK's answer with the subprotocol named as the client named it."""
    match = PROTOCOL_HEADER.search(header)
    if match is None or match.group(2).strip() != NEW:
        return header
    return header[:match.start(2)] + OLD + header[match.end(2):]


async def _read_header(reader: asyncio.StreamReader) -> bytes:
    """Up to and including the blank line that ends an HTTP header (ValueError past the bound)."""
    return await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(CHUNK):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        writer.close()


class SubprotocolBridge:
    """Listens on ``host:port`` and forwards every client to the SDK server at ``127.0.0.1:upstream_port``."""

    def __init__(self, host: str, port: int, upstream_port: int) -> None:
        self._upstream_port = upstream_port
        self._loop = asyncio.new_event_loop()
        self._server: asyncio.base_events.Server | None = None
        self.bridged = 0  # clients that asked for foxglove.websocket.v1
        started = self._loop.run_until_complete(
            asyncio.start_server(self._client, host, port, limit=MAX_HEADER_BYTES))
        self._server = started
        self.port = int(started.sockets[0].getsockname()[1])
        self._thread = threading.Thread(target=self._loop.run_forever, name="foxglove-bridge", daemon=True)
        self._thread.start()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            request, old = _rewrite_offer(await _read_header(reader))
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self._upstream_port, limit=MAX_HEADER_BYTES)
        except (asyncio.TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ValueError, OSError):
            writer.close()  # no handshake, a huge one, or no SDK server behind: this client only
            return
        self.bridged += old
        up_writer.write(request)
        try:
            answer = await _read_header(up_reader)
        except (asyncio.TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ValueError, OSError):
            writer.close()
            up_writer.close()
            return
        writer.write(_rewrite_answer(answer) if old else answer)
        await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))

    def close(self) -> None:
        async def stop() -> None:
            if self._server is not None:
                self._server.close()
            for task in asyncio.all_tasks():
                if task is not asyncio.current_task():
                    task.cancel()

        if self._loop.is_running():
            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(timeout=5)
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5)
        self._loop.close()
