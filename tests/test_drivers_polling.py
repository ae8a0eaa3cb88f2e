"""``wait_until`` (tests/helpers.py): how the driver tests wait for a reader thread.

A test waits for a condition with a generous deadline and asserts on the state, never on the
time; these two tests pin down both outcomes of the wait.
"""

from __future__ import annotations

import threading

from helpers import wait_until


def test_wait_until_sees_a_change_made_by_another_thread():
    flag = threading.Event()
    threading.Timer(0.02, flag.set).start()
    assert wait_until(flag.is_set)


def test_wait_until_gives_up_on_a_condition_that_never_holds():
    assert not wait_until(lambda: False, timeout=0.05)
