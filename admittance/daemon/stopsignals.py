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
def stop_signals_call(handler: Callable[..., Any], *, then: Any = None) -> Iterator[None]:
    """Inside the block SIGINT/SIGTERM call ``handler``; after it, the previous handlers come
    back, or ``then`` (e.g. ``signal.SIG_IGN``) is installed instead.

    A second signal during the stop calls ``handler`` again (a no-op once the stop is under
    way), so it never interrupts the teardown. ``then=SIG_IGN`` is for a process whose work
    ends with the block: after it only the interpreter's exit remains (closing sessions,
    flushing files), and the default action of a late SIGTERM would cut that short (exit -15).

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
            signal.signal(sig, old if then is None else then)
