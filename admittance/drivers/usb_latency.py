"""The FTDI latency timer of a USB serial adapter (U2D2, USB2Dynamixel), checked from sysfs.

An FTDI chip holds a short reply until its 64-byte buffer fills or its latency timer expires,
16 ms by default on Linux: every Dynamixel read then costs up to 16 ms, and a 1 kHz loop is
impossible (shared protocols.md §6). The fix is one sysfs write (or the udev rule in
that `admittance service install` puts in /etc/udev/rules.d, since the value resets on replug); this module finds the
right sysfs file for a port and says so. The port may be a symlink (/dev/serial/by-id/...,
/dev/dynamixel); it is resolved to its tty first. Devices without a timer (ptys, CDC-ACM
ports such as the OptoForce DAQ, non-FTDI adapters) have no such file, and nothing is said.
"""

from __future__ import annotations

import os
from pathlib import Path

WANTED_MS = 1
UDEV_RULE = "99-admittance-ftdi.rules"


def latency_timer_path(port: str, *, sysfs_root: str | Path = "/sys") -> Path:
    """The sysfs file that would hold the latency timer of ``port``'s tty."""
    tty = os.path.basename(os.path.realpath(port))
    return Path(sysfs_root) / "bus" / "usb-serial" / "devices" / tty / "latency_timer"


def read_latency_timer(port: str, *, sysfs_root: str | Path = "/sys") -> int | None:
    """The timer in ms, or None when the device has none (or it cannot be read)."""
    try:
        return int(latency_timer_path(port, sysfs_root=sysfs_root).read_text().strip())
    except (OSError, ValueError):
        return None


def latency_warning(port: str, *, sysfs_root: str | Path = "/sys", wanted_ms: int = WANTED_MS) -> str | None:
    """A one-paragraph warning with the fix when the timer is above ``wanted_ms``, else None."""
    value = read_latency_timer(port, sysfs_root=sysfs_root)
    if value is None or value <= wanted_ms:
        return None
    path = latency_timer_path(port, sysfs_root=sysfs_root)
    return (
        f"the USB serial adapter of {port} has a {value} ms latency timer: every servo reply waits up to "
        f"{value} ms, too slow for the control loop. Set it to {wanted_ms} ms with "
        f"`echo {wanted_ms} | sudo tee {path}`, or install the udev rule {UDEV_RULE} "
        f"(`sudo admittance service install` puts it in /etc/udev/rules.d/; then replug the adapter) "
        f"so that it stays set."
    )
