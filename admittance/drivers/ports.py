"""Serial devices: exclusive opens, the daemon's claim on its devices, and why an open failed.

Two daemons on one servo bus would both run, each sending its own goals (the servo follows
whichever wrote last), and a second reader on a sensor tty steals the first one's bytes. So
every device is taken twice over:

- **The claim** (:func:`claim`): before anything is opened or written, the daemon takes a lock
  file per device for its whole run, ``admittance-<device path, %-escaped>.lock`` in
  :func:`lock_dir`. It is an ``flock``, so it goes with the process (no stale locks after a
  crash), and the file holds the holder's pid for the message a second daemon prints. It is
  taken for the configured path and for the path it resolves to (``/dev/serial/by-id/...`` →
  ``/dev/ttyUSB0``), so two aliases of one adapter still collide. A later replug may give
  the adapter another number; the exclusive open below still guards that.
- **The exclusive open** (:func:`exclusive_serial`, and ``dxl::serial`` in Rust): pyserial's
  ``exclusive=True`` (an ``flock`` on the device itself, taken before pyserial configures the
  port, so a refused open changes nothing) plus ``TIOCEXCL`` (the kernel then refuses any
  other unprivileged ``open``). ``TIOCEXCL`` is cleared again before closing, because it
  outlives the descriptor on a tty that stays open elsewhere (a simulated device's pty).

Root bypasses ``TIOCEXCL`` but not the locks. The messages name the device once and add the
likely fix for the usual causes (unplugged, no permission, in use: with the holder's pid).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import functools
import os
import tempfile
import termios
import urllib.parse
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from admittance.errors import DeviceError

LOCK_DIR_ENV = "ADMITTANCE_LOCK_DIR"
SYSTEM_LOCK_DIR = "/run/lock"

_HINTS = {
    errno.ENOENT: "no such device (is it plugged in? check the path, e.g. ls /dev/serial/by-id/)",
    errno.EACCES: "permission denied (add the user to the 'dialout' group, then log in again)",
    errno.ENXIO: "no such device or address (the adapter was unplugged?)",
}
_IN_USE = (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK)


def open_error_message(what: str, port: str, exc: BaseException) -> str:
    """One line: ``cannot open <what> <port>: <reason>``."""
    code = getattr(exc, "errno", None)
    if code in _IN_USE:
        return f"cannot open {what} {port}: {in_use_reason(port)}"
    reason = _HINTS.get(code) if code is not None else None
    return f"cannot open {what} {port}: {reason or exc}"


def in_use_reason(port: str) -> str:
    pid = lock_holder(port)
    holder = f" (pid {pid})" if pid is not None else ""
    return f"the device is busy: another process has it open{holder}; is another daemon running on it?"


def lock_holder(path: str) -> int | None:
    """The pid holding an ``flock`` on ``path``'s device node, from /proc/locks, if any.

    Lines read ``N: FLOCK  ADVISORY  WRITE pid MAJ:MIN:INODE 0 EOF`` (device numbers in hex);
    a waiter's line has ``->`` in the second field and is skipped.
    """
    try:
        st = os.stat(path)
        with open("/proc/locks", encoding="ascii", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    want = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    for line in lines:
        fields = line.split()
        if len(fields) < 6 or fields[1] != "FLOCK":
            continue
        try:
            major, minor, inode = fields[5].split(":")
            if (int(major, 16), int(minor, 16), int(inode)) == want:
                return int(fields[4])
        except ValueError:
            continue
    return None


# ---------------------------------------------------------------------------------------------
# Exclusive opens


def exclusive_serial(port: str, baudrate: int, **options: Any) -> Any:
    """A pyserial port opened exclusively (``flock`` + ``TIOCEXCL``); its ``close`` clears
    ``TIOCEXCL``. Raises what pyserial raises (``SerialException`` with the errno)."""
    return _exclusive_class()(port, baudrate, exclusive=True, **options)


@functools.cache
def _exclusive_class() -> type:
    import serial  # pyserial; imported on first use, so that importing drivers stays cheap

    class ExclusiveSerial(serial.Serial):
        """pyserial's port with ``TIOCEXCL`` on top of its ``exclusive=True`` flock."""

        def open(self) -> None:
            super().open()
            with contextlib.suppress(OSError):  # a non-tty (a test's file) refuses it: no matter
                fcntl.ioctl(self.fd, termios.TIOCEXCL)

        def close(self) -> None:
            if self.is_open and self.fd is not None:
                with contextlib.suppress(OSError):  # EIO on a device that is gone
                    fcntl.ioctl(self.fd, termios.TIOCNXCL)
            super().close()

    return ExclusiveSerial


# ---------------------------------------------------------------------------------------------
# The claim


def lock_dir() -> Path:
    """Where claims live: ``$ADMITTANCE_LOCK_DIR``, else /run/lock (shared by every user on
    Debian-like systems), else ``$XDG_RUNTIME_DIR``, else the temporary directory: the first
    that exists and is writable. Daemons that must exclude each other need the same one."""
    candidates = [os.environ.get(LOCK_DIR_ENV), SYSTEM_LOCK_DIR, os.environ.get("XDG_RUNTIME_DIR"), tempfile.gettempdir()]
    for candidate in candidates:
        if candidate and os.path.isdir(candidate) and os.access(candidate, os.W_OK | os.X_OK):
            return Path(candidate)
    raise DeviceError(f"no writable directory for device locks (set {LOCK_DIR_ENV})")


def lock_path(device: str, directory: Path | None = None) -> Path:
    """The lock file of one device path (absolute, %-escaped into one file name)."""
    name = urllib.parse.quote(os.path.abspath(device), safe="")
    return (directory or lock_dir()) / f"admittance-{name}.lock"


class Claim:
    """Locks held on devices; :meth:`release` (or leaving :func:`claim`) lets them go."""

    def __init__(self) -> None:
        self.paths: list[Path] = []
        self._fds: list[int] = []

    def take(self, device: str, directory: Path) -> None:
        for name in dict.fromkeys([os.path.abspath(device), os.path.realpath(device)]):
            path = lock_path(name, directory)
            if path in self.paths:
                continue
            fd = _open_lock_file(path)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise DeviceError(_held_message(device, path)) from None
            self._fds.append(fd)
            self.paths.append(path)
            with contextlib.suppress(OSError):  # a lock file of another user's: read-only for us
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)

    def release(self) -> None:
        for fd in self._fds:
            os.close(fd)  # the flock goes with it; the file stays (deleting it would race)
        self._fds.clear()
        self.paths.clear()


@contextlib.contextmanager
def claim(devices: Iterable[str]) -> Iterator[Claim]:
    """Hold every device in ``devices`` for the daemon alone, for the ``with`` block.

    Raises a one-line DeviceError naming the device and the holding pid when another daemon
    has one of them; nothing is held then. Empty names are skipped.
    """
    held = Claim()
    try:
        wanted = [device for device in devices if device]
        directory = lock_dir() if wanted else None  # nothing to claim needs no lock directory
        for device in wanted:
            held.take(device, directory)
        yield held
    finally:
        held.release()


def _open_lock_file(path: Path) -> int:
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    except PermissionError:
        # Made by another user (0644 under their umask): a read-only descriptor can flock too.
        try:
            return os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        except OSError as exc:
            raise DeviceError(f"cannot take the lock {path}: {exc.strerror}") from None
    except OSError as exc:
        raise DeviceError(f"cannot take the lock {path}: {exc.strerror}") from None
    with contextlib.suppress(OSError):  # shared /run/lock: let other users' daemons lock it too
        os.fchmod(fd, 0o666)
    return fd


def _held_message(device: str, path: Path) -> str:
    try:
        pid = path.read_text(encoding="ascii", errors="replace").strip()
    except OSError:
        pid = ""
    holder = f"pid {pid}" if pid.isdigit() else "another process"
    return f"cannot claim {device}: another admittance daemon has it ({holder}, lock {path}); stop that one first"
