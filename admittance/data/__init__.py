"""Data shipped inside the package: the daemon's default configurations and the fitted plants.

- ``bench.toml``    what ``admittance run`` runs without ``--config`` (the simulated bench);
- ``example.toml``  a real bench, every key shown (``admittance run --print-example-config``);
- ``params/*.toml`` the thesis's fitted plant parameters per motor (Contract 2);
- ``foxglove/*.json`` Foxglove layouts for a ``session.mcap`` and the live view (docs/foxglove.md).

Everything is read through :mod:`importlib.resources`, so a wheel installed anywhere finds it
and no code path depends on where a checkout of the repository lies.
"""

from __future__ import annotations

import atexit
import contextlib
import re
from importlib import resources
from pathlib import Path

PARAMS = "params"
_extracted = contextlib.ExitStack()  # files extracted from a zipped install, removed at exit
atexit.register(_extracted.close)


def path(*parts: str) -> Path:
    """A packaged file as a real path (extracted to a temporary file if the install is zipped)."""
    resource = resources.files(__name__).joinpath(*parts)
    if isinstance(resource, Path):
        return resource
    return _extracted.enter_context(resources.as_file(resource))


def bench_config() -> Path:
    return path("bench.toml")


def example_config() -> Path:
    return path("example.toml")


def params_name(model: str) -> str:
    """The file name of a model's fitted parameters: lower case, no punctuation (MX-64 → mx64.toml)."""
    return re.sub(r"[^a-z0-9]", "", model.lower()) + ".toml"


def params_file(model: str) -> Path:
    """The shipped fit of ``model`` (it may not exist: check ``is_file()``)."""
    return path(PARAMS, params_name(model))


def packaged(relative: str) -> Path | None:
    """A relative path of a configuration (``params/mx64.toml``, or the checkout's former
    ``config/params/mx64.toml``) looked up among the shipped files; None if it is not there."""
    parts = Path(relative).parts
    if parts[:1] == ("config",):
        parts = parts[1:]
    if not parts or ".." in parts:
        return None
    candidate = path(*parts)
    return candidate if candidate.is_file() else None
