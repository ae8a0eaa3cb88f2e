"""Sleep until an absolute CLOCK_MONOTONIC deadline: ``clock_nanosleep(TIMER_ABSTIME)`` by ctypes.

A periodic source that sleeps to absolute deadlines (``t0 + k·period``) keeps its own clock, as
hardware does: a late wake-up does not shift the next ones. Python's ``time.sleep`` is relative.
Used by bench/pty_handoff.py (its writer) and bench/loop_timing.py (its pty DAQ, a bare
``python -c`` that is given this file's source): so this file imports nothing of the project.
"""
import ctypes
import time

TIMER_ABSTIME, EINTR = 1, 4
_libc = ctypes.CDLL(None, use_errno=True)


class Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


def sleep_until(ns: int) -> None:
    """Sleeps until CLOCK_MONOTONIC reads ``ns``; a signal's interruption sleeps on."""
    ts = Timespec(ns // 1_000_000_000, ns % 1_000_000_000)
    while _libc.clock_nanosleep(time.CLOCK_MONOTONIC, TIMER_ABSTIME, ctypes.byref(ts), None) == EINTR:
        pass
