"""The mock bench's control socket: fault commands from another process, one line each.

``admittance mock-bench --control PATH`` listens on a Unix stream socket at PATH. A client
writes one command per line (:mod:`admittance.mockbench.faults`) and reads one JSON reply line
per command, so a test knows a fault is in effect before it looks for its consequences::

    printf 'bus unplug\\n' | socat - UNIX-CONNECT:/tmp/bench.sock    # {"ok": true, "changed": true}

One client is served at a time, each line at most 1 KiB (a longer one is refused and the
connection closed). :func:`send` is the client side, for tests and scripts.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import stat
import threading
from typing import Any

from admittance.errors import DeviceError
from admittance.mockbench.faults import MAX_LINE, run_command

POLL_S = 0.2


class ControlServer:
    """Serves fault commands for ``bench`` on a Unix socket at ``path`` from its own thread."""

    def __init__(self, bench: Any, path: str):
        self.bench = bench
        self.path = path
        self.commands = 0
        self._stop = threading.Event()
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            if os.path.lexists(path) and _is_socket(path):
                os.unlink(path)  # a socket left by an earlier bench; never any other file
            self._sock.bind(path)
            self._sock.listen(1)
        except OSError as exc:
            self._sock.close()
            raise DeviceError(f"--control: cannot listen on {path}: {exc.strerror or exc}") from None
        self._sock.settimeout(POLL_S)
        self._thread = threading.Thread(target=self._serve, name="mock-bench-control", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self._sock.close()
        with contextlib.suppress(OSError):
            os.unlink(self.path)

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                self._serve_client(conn)

    def _serve_client(self, conn: socket.socket) -> None:
        conn.settimeout(POLL_S)
        pending = b""
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            pending += data
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                self._reply(conn, run_command(self.bench, line.decode("utf-8", errors="replace")))
            if len(pending) > MAX_LINE:
                self._reply(conn, {"ok": False, "error": f"a command is at most {MAX_LINE} characters"})
                return

    def _reply(self, conn: socket.socket, reply: dict[str, Any]) -> None:
        self.commands += 1
        with contextlib.suppress(OSError):
            conn.sendall(json.dumps(reply, default=str).encode() + b"\n")


def _is_socket(path: str) -> bool:
    return stat.S_ISSOCK(os.lstat(path).st_mode)


def send(path: str, *commands: str, timeout: float = 30.0) -> list[dict[str, Any]]:
    """Send ``commands`` to the bench's control socket; their replies, in order."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(path)
        replies = []
        reader = sock.makefile("rb")
        for command in commands:
            sock.sendall(command.encode() + b"\n")
            replies.append(json.loads(reader.readline()))
        return replies
