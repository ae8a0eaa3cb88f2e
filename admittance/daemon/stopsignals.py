"""SIGINT and SIGTERM as a stop request, for a block of code.

The handler only records the request (it sets an event); the stop itself (hold, torque
policy, stats) runs on the main thread, where it is safe. A small module of its own because
the command line installs it before its slow imports (zenoh, NumPy, the extension), so a
signal that arrives while the daemon still loads is a clean stop too, not a half-started kill;
the supervisor installs the same thing around its run for callers other than the CLI.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_signals_call(handler: Callable[..., Any]) -> Iterator[None]:
    """Inside the block SIGINT/SIGTERM call ``handler``; the previous handlers come back after.

    Python delivers signals to the main thread only, so elsewhere this does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
