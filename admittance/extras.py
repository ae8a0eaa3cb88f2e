"""Optional dependencies: what a robot can leave out, and the one-line hint when it is missing.

The default install runs the daemon, the simulated bench and identification. A robot that only
runs the loop does not need plotting, and one with a serial force sensor does not need
python-can; each of these comes with an extra (``pip install 'admittance[plots]'``). A command
that needs a missing one stops with one line that names the extra, never a traceback.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from admittance.errors import ConfigError

# import name -> (distribution, extra)
OPTIONAL = {
    "matplotlib": ("matplotlib", "plots"),
    "can": ("python-can", "can"),
}


class MissingExtra(ConfigError):
    """An optional package that this command needs is not installed."""


def require(module: str, purpose: str) -> ModuleType:
    """Import an optional ``module`` (a top-level name of OPTIONAL, or a submodule of one)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        top = module.partition(".")[0]
        if top not in OPTIONAL or exc.name not in (top, module):
            raise  # a broken install of something else: keep the real error
        dist, extra = OPTIONAL[top]
        raise MissingExtra(f"{purpose} needs {dist}, which is not installed: pip install 'admittance[{extra}]'") from None
