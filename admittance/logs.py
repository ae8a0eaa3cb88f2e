"""Logging of the daemon-side commands (``run``, ``mock-bench``, ``router``): the standard
``logging`` module, one handler on stderr, two line formats.

- On a terminal or in a file: ``admittance run: warning: the FTDI latency timer is 16 ms``
  (``admittance <command>: `` then ``debug: ``/``warning: ``/``error: `` for those levels,
  nothing for info), no timestamp: a person reads it live, and the lines stay the ones the
  daemon has always printed.
- Under systemd, when stderr *is* the journal (``$JOURNAL_STREAM`` names stderr's device and
  inode, which is how systemd tells a service so): ``<4>the FTDI latency timer is 16 ms``. The
  ``<N>`` prefix is the syslog priority, which journald reads and strips (``SyslogLevelPrefix=``
  is on by default), so ``journalctl -p warning`` filters and colours them; no timestamp and no
  program name, since the journal adds both. ``$INVOCATION_ID`` alone is not enough: a service
  may send stderr to a file (``StandardError=file:...``), where plain lines are the right ones.

Levels: ``--verbose`` shows debug lines (the start order's steps, the status every second),
``--quiet`` only warnings and errors; the default shows info (what runs, parameter changes,
the one-line summary at stop). Other libraries' loggers (python-can, pyserial) show warnings,
and info with ``--verbose``.

What a command prints as its product (``run --check``, ``get``, ``mock-bench --print-ports``)
is not logging: it goes to stdout with ``print``. Everything else the daemon says goes through
a logger named under ``admittance``.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import time
from collections.abc import Callable, Iterator
from typing import TextIO

ROOT = "admittance"
# syslog priorities (sd-daemon(3)): the prefixes journald understands.
SYSLOG_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}
LEVEL_WORD = {logging.DEBUG: "debug: ", logging.WARNING: "warning: ", logging.ERROR: "error: ",
              logging.CRITICAL: "error: "}
RATE_PERIOD_S = 10.0

_handler: logging.Handler | None = None
_command: str | None = None  # the command _handler was set up for


def add_verbosity_args(parser: argparse.ArgumentParser) -> None:
    """``-v/--verbose`` and ``-q/--quiet`` (exclusive) on a daemon-side command."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("-v", "--verbose", action="store_const", dest="verbosity", const=1, default=0,
                       help="also log debug lines: the start order's steps, the status every second "
                            "(default: info: what runs, parameter changes, the summary at stop)")
    group.add_argument("-q", "--quiet", action="store_const", dest="verbosity", const=-1,
                       help="log only warnings and errors (default: info)")


def journal_stream(stream: TextIO) -> bool:
    """Whether ``stream`` is the journal: systemd sets ``JOURNAL_STREAM=<dev>:<inode>`` of the
    stream it connected to the journal; a redirection (``2>file``) changes the inode."""
    expected = os.environ.get("JOURNAL_STREAM", "")
    if not expected:
        return False
    try:
        st = os.fstat(stream.fileno())
    except (OSError, ValueError, AttributeError):  # no real file behind it (a test's StringIO)
        return False
    return expected == f"{st.st_dev}:{st.st_ino}"


class PlainFormatter(logging.Formatter):
    """``admittance <command>: [level word]message``: the daemon's lines on a terminal."""

    def __init__(self, command: str) -> None:
        super().__init__()
        self.prefix = f"admittance {command}: "

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        return self.prefix + LEVEL_WORD.get(record.levelno, "") + text


class JournalFormatter(logging.Formatter):
    """``<N>message``, every line of a multi-line message prefixed (journald splits lines)."""

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{SYSLOG_PRIORITY.get(record.levelno, 6)}>"
        return "\n".join(prefix + line for line in super().format(record).splitlines() or [""])


class StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at each line (as logging's last resort does), so a
    handler set up by one in-process run never writes to a stream closed since (tests)."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self) -> TextIO:  # type: ignore[override]
        return sys.stderr

    @stream.setter
    def stream(self, _value: TextIO) -> None:
        pass


def configure(command: str, verbosity: int = 0, stream: TextIO | None = None,
              journal: bool | None = None) -> logging.Handler:
    """One handler on the root logger for ``command`` (on ``stream``, default stderr); a
    second call replaces the first. ``journal`` None: detected from ``$JOURNAL_STREAM``."""
    global _handler, _command
    handler = logging.StreamHandler(stream) if stream is not None else StderrHandler()
    handler.setFormatter(JournalFormatter() if (journal_stream(handler.stream) if journal is None else journal)
                         else PlainFormatter(command))
    root = logging.getLogger()
    if _handler is not None:
        root.removeHandler(_handler)
    root.addHandler(handler)
    _handler, _command = handler, command
    root.setLevel(logging.INFO if verbosity > 0 else logging.WARNING)
    logging.getLogger(ROOT).setLevel(logging.DEBUG if verbosity > 0 else logging.WARNING if verbosity < 0
                                     else logging.INFO)
    return handler


class _CallHandler(logging.Handler):
    def __init__(self, say: Callable[[str], None]) -> None:
        super().__init__()
        self.say = say

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.say(LEVEL_WORD.get(record.levelno, "") + self.format(record))
        except Exception:  # a broken sink must not break the code that logs
            self.handleError(record)


@contextlib.contextmanager
def forwarded(say: Callable[[str], None], level: int = logging.INFO) -> Iterator[None]:
    """For the block, the package's lines at ``level`` and above go to ``say`` only (the setup
    wizard shows a dry run's daemon lines in its own output)."""
    ours = logging.getLogger(ROOT)
    handler = _CallHandler(say)
    saved = ours.level, ours.propagate
    ours.addHandler(handler)
    ours.setLevel(level)
    ours.propagate = False
    try:
        yield
    finally:
        ours.removeHandler(handler)
        ours.setLevel(saved[0])
        ours.propagate = saved[1]


def reset() -> None:
    """Undo :func:`configure` when a command ends, so that the next command run in the same
    process (tests call ``admittance.cli.main`` many times) starts without its handler."""
    global _handler
    if _handler is not None:
        logging.getLogger().removeHandler(_handler)
        _handler = None
        logging.getLogger().setLevel(logging.WARNING)
        logging.getLogger(ROOT).setLevel(logging.NOTSET)


def report_error(command: str, text: str) -> None:
    """The one line of an error that ends a command: through logging when the command set it
    up (so that under systemd it carries its priority), else plainly on stderr."""
    if _handler is not None and _command == command and _handler in logging.getLogger().handlers:
        logging.getLogger(ROOT).error("%s", text)
    else:
        print(f"admittance {command}: error: {text}", file=sys.stderr)


class RateLimitedLog:
    """At most ``burst`` lines per ``key`` per ``period`` seconds; the first line after a pause
    says how many were held back. A hostile peer or a failing device must not flood the journal,
    and the first line of a kind is never delayed."""

    def __init__(self, logger: logging.Logger, period: float = RATE_PERIOD_S, burst: int = 1,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._logger = logger
        self._period = period
        self._burst = burst
        self._clock = clock
        self._window: dict[str, tuple[float, int]] = {}  # key -> (window start, lines in it)
        self._held: dict[str, int] = {}

    def __call__(self, key: str, text: str, level: int = logging.WARNING) -> bool:
        """Log ``text`` unless ``key`` used up its lines; whether it was logged."""
        now = self._clock()
        start, lines = self._window.get(key, (now, 0))
        if now - start >= self._period:
            start, lines = now, 0
        if lines >= self._burst:
            self._held[key] = self._held.get(key, 0) + 1
            return False
        self._window[key] = (start, lines + 1)
        held = self._held.pop(key, 0)
        self._logger.log(level, "%s", text + (f" ({held} more like it held back)" if held else ""))
        return True
