"""The folders of the mock bench's stable links (``dxl``, ``sensor``): made per bench, and those
left behind by a process that died without stopping its bench (SIGKILL) removed by the next one.

Why a module of its own: the bench only needs a folder; what makes a leftover folder safe to
remove (its name, its owner, a dead pid, nothing in it but the bench's links) is a concept of
its own, tested on its own (tests/test_mockbench_link_dirs.py).
"""

from __future__ import annotations

import os
import re
import stat
import tempfile

# The folder of a bench's stable links: ``<tmp>/admittance-bench-<pid>-<random>``, named after the
# process that made it, so that one left behind by a process that died without stop() (SIGKILL)
# is recognised and removed by the next bench made on this machine.
LINK_DIR_PREFIX = "admittance-bench-"
_LINK_DIR_NAME = re.compile(re.escape(LINK_DIR_PREFIX) + r"([1-9][0-9]*)-[a-z0-9_]+")
_LINK_NAME = re.compile(r"(dxl|sensor)(\.[0-9]+\.new)?")  # the links, and point_link's temporary ones


def new_link_dir() -> str:
    """A private folder for this bench's links, made after removing the orphans of dead processes."""
    remove_orphan_link_dirs()
    return tempfile.mkdtemp(prefix=f"{LINK_DIR_PREFIX}{os.getpid()}-")


def remove_orphan_link_dirs(root: str | None = None) -> list[str]:
    """Remove the link folders whose process is gone; returns their paths. Only a directory named
    as new_link_dir names them, owned by this user, after a pid that no longer runs, holding
    nothing but the bench's symlinks: anything else is left alone (a reused pid keeps its folder)."""
    removed = []
    for entry in os.scandir(root or tempfile.gettempdir()):
        match = _LINK_DIR_NAME.fullmatch(entry.name)
        if match is None or _process_alive(int(match.group(1))):
            continue
        try:
            if _remove_link_dir(entry.path):
                removed.append(entry.path)
        except OSError:  # another bench's sweep was first, or it changed under us: not ours to force
            continue
    return removed


def _remove_link_dir(path: str) -> bool:
    info = os.lstat(path)
    if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid():
        return False
    entries = list(os.scandir(path))
    if not all(e.is_symlink() and _LINK_NAME.fullmatch(e.name) for e in entries):
        return False
    for e in entries:
        os.unlink(e.path)
    os.rmdir(path)
    return True


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True
