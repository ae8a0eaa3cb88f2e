"""Output folders: a command writes into a new or empty folder, or, with ``--force``, replaces
the files of its own kinds there. Old trial files beside a new manifest would be read as one
dataset (or one report), so a non-empty folder is never written into silently.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from admittance.errors import ConfigError

DATASET_FILES = ("manifest.toml", "*.csv", "truth.json")


def check(folder: Path, force: bool, option: str, patterns: Sequence[str] = DATASET_FILES) -> None:
    """Refuse a non-empty ``folder`` unless ``force``: called before any work, so nothing is lost."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{option} {folder}: exists and is not a folder")
    entries = sorted(p.name for p in folder.iterdir()) if folder.exists() else []
    if entries and not force:
        shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
        raise ConfigError(f"{option} {folder}: not empty ({shown}); pass --force to replace its "
                          f"{', '.join(patterns)} files, or choose a new folder")


def clear(folder: Path, option: str, patterns: Sequence[str] = DATASET_FILES) -> Path:
    """Create ``folder``, or remove its files matching ``patterns`` (other files stay): right
    before the new ones are written."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for pattern in patterns:
            for path in folder.glob(pattern):
                if path.is_file():
                    path.unlink()
    except OSError as exc:
        raise ConfigError(f"{option} {folder}: cannot prepare it ({exc.strerror})") from None
    return folder


def write_texts(folder: Path, files: dict[str, str]) -> None:
    """Write each ``name: text`` into ``folder`` (made if missing); a failure is one ConfigError line."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for name, text in files.items():
            (folder / name).write_text(text)
    except OSError as exc:
        raise ConfigError(f"{folder}: cannot write ({exc.strerror})") from None
