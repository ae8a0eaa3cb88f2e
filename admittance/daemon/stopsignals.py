"""SIGINT and SIGTERM as a stop request, for a block of code; SIGHUP, SIGUSR1 and SIGUSR2 too.

SIGHUP (a closed terminal, a stray ``kill -HUP``) and SIGUSR1/2 (a tool that meant another
process) would otherwise kill the daemon at once: no stop line, no stats, an unfinished MCAP,
no torque policy, and an exit systemd counts as clean. They stop it cleanly instead, and the
stop is told as what it is: an *unexpected* signal (``StopRequest.unexpected``), which the
supervisor turns into exit 75 so that systemd restarts a service nobody meant to stop.

The handler only records the request (it sets a :class:`StopRequest`); the stop itself (hold,
torque policy, stats) runs on the main thread, where it is safe. A small module of its own
because the command line installs it before its slow imports (zenoh, NumPy, the extension), so
a signal that arrives while the daemon still loads is a clean stop too, not a half-started
kill; the supervisor installs the same thing around its run for callers other than the CLI.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# Signals whose default action is death but that nobody sends to stop a daemon on purpose.
UNEXPECTED_SIGNALS = (signal.SIGHUP, signal.SIGUSR1, signal.SIGUSR2)


class StopRequest:
    """A stop request that a signal handler may set: ``set``, ``is_set``, ``wait(timeout)``.

    Why not ``threading.Event``: its ``set`` takes a lock, and a Python signal handler runs on
    the main thread between two bytecodes, possibly while that same thread holds the lock (in
    ``Event.wait``, or in the ``set`` of a first signal's handler when a second signal arrives).
    The handler then waits for itself forever: a SIGINT followed by a SIGTERM hung the daemon
    about once in 40 stops. Here ``set`` takes no lock: it stores a flag and writes a byte to a
    non-blocking pipe, and ``wait`` sleeps in ``select`` on the pipe's other end.
    """

    def __init__(self) -> None:
        self._set = False
        self.signal: int | None = None  # the first signal that set it, if a signal did
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)

    def set(self, signum: int | None = None) -> None:
        if not self._set:
            self.signal = signum
        self._set = True
        try:
            os.write(self._write, b"\0")
        except OSError:  # the pipe is full (set many times already) or closed: the flag is what counts
            pass

    def is_set(self) -> bool:
        return self._set

    def unexpected(self) -> str | None:
        """The name of the unexpected signal (SIGHUP, SIGUSR1/2) that stopped it, if one did."""
        if self.signal in UNEXPECTED_SIGNALS:
            return signal.Signals(self.signal).name
        return None

    def wait(self, timeout: float | None = None) -> bool:
        """Until set or ``timeout`` seconds passed; whether it is set."""
        if not self._set:
            select.select([self._read], [], [], timeout)
        return self._set

    def __del__(self) -> None:
        for fd in (self._read, self._write):
            with contextlib.suppress(OSError):
                os.close(fd)


@contextlib.contextmanager
def stop_signals_call(handler: Callable[..., Any], *, then: Any = None) -> Iterator[None]:
    """Inside the block SIGINT/SIGTERM (and the unexpected SIGHUP/SIGUSR1/SIGUSR2) call
    ``handler(signum, frame)``; after it, the previous handlers come back, or ``then`` (e.g.
    ``signal.SIG_IGN``) is installed instead.

    A second signal during the stop calls ``handler`` again (a no-op once the stop is under
    way), so it never interrupts the teardown. ``then=SIG_IGN`` is for a process whose work
    ends with the block: after it only the interpreter's exit remains (closing sessions,
    flushing files), and the default action of a late SIGTERM would cut that short (exit -15).

    Python delivers signals to the main thread only, so elsewhere this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in (*STOP_SIGNALS, *UNEXPECTED_SIGNALS)}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old if then is None else then)
