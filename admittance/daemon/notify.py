"""systemd's notify protocol by hand: READY, STATUS, STOPPING and a watchdog tied to the loop.

Why not ``sdnotify`` or ``systemd-python``: the first swallows every error with a bare
except, the second needs libsystemd headers and a compiler. The protocol is one AF_UNIX
datagram per message to ``$NOTIFY_SOCKET`` (a leading ``@`` names an abstract socket).

The watchdog ping is not "the Python process is alive": it is sent only while the RT loop's
heartbeat counter advances *and* the loop is healthy (its bus, servos and sensor within what
the fault policy allows: ``faults.FaultWatch.health``), so a stalled RT thread, or one that
cycles on a dead bus, stops the pings and systemd restarts the service (man
sd_watchdog_enabled(3): ping at half of ``$WATCHDOG_USEC``).
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Mapping


class Notifier:
    """Sends notify messages; does nothing when not started by systemd (no $NOTIFY_SOCKET)."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        self.address = "\0" + address[1:] if address.startswith("@") else address
        self.watchdog_usec = _watchdog_usec(env)

    @property
    def enabled(self) -> bool:
        return bool(self.address)

    def send(self, *lines: str) -> bool:
        """Send one datagram; False when there is no socket, systemd is gone or not reading.

        Non-blocking: a datagram socket whose reader lags blocks the sender once its queue is
        full, and the supervisor's main loop must never wait on systemd.
        """
        if not self.address:
            return False
        flags = socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK
        with socket.socket(socket.AF_UNIX, flags) as sock:
            try:
                sock.sendto("\n".join(lines).encode(), self.address)
            except OSError:  # BlockingIOError included: drop rather than stall
                return False
        return True

    def ready(self, status: str = "") -> bool:
        return self.send("READY=1", *([f"STATUS={status}"] if status else []))

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={text}")

    def stopping(self, status: str = "") -> bool:
        return self.send("STOPPING=1", *([f"STATUS={status}"] if status else []))


def _watchdog_usec(env: Mapping[str, str]) -> int:
    """$WATCHDOG_USEC when it is meant for this process, else 0 (sd_watchdog_enabled semantics)."""
    pid = env.get("WATCHDOG_PID", "")
    if pid and pid != str(os.getpid()):
        return 0
    try:
        return max(int(env.get("WATCHDOG_USEC", "0")), 0)
    except ValueError:
        return 0


class Watchdog:
    """Pings WATCHDOG=1 every half period, but only when ``heartbeat()`` moved since the last ping
    and ``healthy()`` says the loop is well.

    It has no thread of its own: the supervisor's main loop calls :meth:`poll` every tick, so
    the pings stop when either the RT loop or the supervisor stalls, and the loop object is
    only ever touched from the main thread.
    """

    def __init__(self, notifier: Notifier, heartbeat: Callable[[], int],
                 clock: Callable[[], float] = time.monotonic, healthy: Callable[[], bool] = lambda: True) -> None:
        self._notifier = notifier
        self._heartbeat = heartbeat
        self._healthy = healthy
        self._clock = clock
        self._last_beat: int | None = None
        self._next_check = clock()
        self.pings = 0
        self.missed = 0  # checks where the loop had not advanced
        self.unhealthy = 0  # checks where it advanced but was not healthy

    @property
    def enabled(self) -> bool:
        return self._notifier.enabled and self._notifier.watchdog_usec > 0

    @property
    def interval_s(self) -> float:
        return self._notifier.watchdog_usec / 2e6

    def poll(self) -> bool:
        """Check when half a period has passed; ping if the loop advanced. True when it pinged."""
        now = self._clock()
        if not self.enabled or now < self._next_check:
            return False
        self._next_check = now + self.interval_s
        beat = self._heartbeat()
        advanced = beat != self._last_beat
        self._last_beat = beat
        if not advanced:
            self.missed += 1
            return False
        if not self._healthy():
            self.unhealthy += 1
            return False
        if self._notifier.send("WATCHDOG=1"):
            self.pings += 1
            return True
        return False
