"""``wait_until``: how the driver tests wait for a reader thread without timed assertions.

The other driver test modules import it from here (pytest puts tests/ on sys.path); a test
waits for a condition with a generous deadline and asserts on the state, never on the time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


def wait_until(condition: Callable[[], bool], timeout: float = 10.0) -> bool:
    """Poll ``condition`` every 10 ms; True as soon as it holds, False at the deadline."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return bool(condition())


def test_wait_until_sees_a_change_made_by_another_thread():
    flag = threading.Event()
    threading.Timer(0.02, flag.set).start()
    assert wait_until(flag.is_set)


def test_wait_until_gives_up_on_a_condition_that_never_holds():
    assert not wait_until(lambda: False, timeout=0.05)
