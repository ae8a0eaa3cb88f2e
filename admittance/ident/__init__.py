"""System identification of a servo joint from pendulum data (``admittance identify``).

The pipeline, one module per step:

- (``admittance.formats.dataset``: read and validate a dataset folder → ``Dataset``;
  ``formats.converters``: recorder formats and conversion to datasets)
- ``split``: the deterministic held-out and validation picks
- ``equation_error`` (with ``smoothing``): smoothed derivatives and a bounded linear fit, the
  starting point
- ``model`` / ``fit``: the Rust batch simulator and a structured Levenberg–Marquardt on the
  output error (simulated − measured angle), shared parameters + per-trial initial states
- ``effects``: rank candidate effects on the residual, admit them on validation trials
- ``residual``: whiteness and where the residual is large; ``angle_sensor``: what the angle sensor
  (motion capture or an encoder) does to the data
- ``identify``: the orchestration and its result (JSON, parameter file)
- ``report``: Markdown + PNG report; ``synthetic``: datasets with known truth

Datasets and parameter files are formats (``admittance.formats``); the thesis's own procedures
(``admittance thesis``, ``breakaway``, ``predict``) are the package ``admittance.thesis``.
``tools_cli`` registers ``admittance ladder`` (chosen effect sets scored by identify's
cross-validation, ``ladder``) and ``admittance convert`` (``formats.converters``).

Python API (what ``admittance identify`` does)::

    from admittance.ident import load_dataset, identify_dataset, IdentifySettings, write_report
    result = identify_dataset(load_dataset("data/mx64"), IdentifySettings(friction="stick"))
    result.to_json()            # the datasets.md object
    result.write_params("mx64.toml")
    write_report(result, "report/")

Heavy modules load on first use, so importing this package stays cheap.
"""

from __future__ import annotations

from importlib import import_module

_EXPORTS = {
    "TrialData": "admittance.formats.dataset",
    "Dataset": "admittance.formats.dataset",
    "load_dataset": "admittance.formats.dataset",
    "IdentifySettings": "admittance.ident.identify",
    "IdentifyResult": "admittance.ident.identify",
    "identify_dataset": "admittance.ident.identify",
    "write_report": "admittance.ident.report",
    "SynthSpec": "admittance.ident.synthetic",
    "generate": "admittance.ident.synthetic",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'admittance.ident' has no attribute {name!r}")
