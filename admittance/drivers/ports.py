"""Why a serial device could not be opened, in words a user can act on.

pyserial's messages repeat the path and the errno text ("could not open port X: [Errno 2] No
such file or directory: 'X'"); the readers and the servo bus name the device once and add
the likely fix for the usual causes (unplugged, no permission, already in use).
"""

from __future__ import annotations

import errno

_HINTS = {
    errno.ENOENT: "no such device (is it plugged in? check the path, e.g. ls /dev/serial/by-id/)",
    errno.EACCES: "permission denied (add the user to the 'dialout' group, then log in again)",
    errno.EBUSY: "the device is busy (another program has it open)",
    errno.ENXIO: "no such device or address (the adapter was unplugged?)",
}


def open_error_message(what: str, port: str, exc: BaseException) -> str:
    """One line: ``cannot open <what> <port>: <reason>``."""
    code = getattr(exc, "errno", None)
    reason = _HINTS.get(code) if code is not None else None
    return f"cannot open {what} {port}: {reason or exc}"
