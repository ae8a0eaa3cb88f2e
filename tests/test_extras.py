"""A command that needs an optional package that is not installed says which extra to install,
in one line, before doing any work (the default install leaves out plots and python-can)."""

from __future__ import annotations

import sys

import pytest

from admittance.cli import main
from admittance.extras import MissingExtra, require


@pytest.fixture
def without(monkeypatch):
    """Make ``import NAME`` fail as it does when the package is not installed."""

    def hide(*names: str) -> None:
        for name in names:
            for loaded in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
                monkeypatch.delitem(sys.modules, loaded)
            monkeypatch.setitem(sys.modules, name, None)

    return hide


def test_require_names_the_extra(without):
    without("matplotlib")
    with pytest.raises(MissingExtra, match=r"pip install 'admittance\[plots\]'"):
        require("matplotlib.pyplot", "a plot")


def test_require_passes_unrelated_import_errors_through():
    with pytest.raises(ImportError):
        require("admittance_no_such_module", "nothing")


@pytest.mark.parametrize("argv, extra", [
    (["identify", "no-such-dir", "--json", "out.json", "--report", "rep"], "plots"),
    (["predict", "no-such-dir", "--params", "p.toml", "--out", "out"], "plots"),
    (["mock-bench", "--sensor", "can", "--duration", "0.1"], "can"),
])
def test_commands_stop_with_one_line_before_any_work(without, capsys, tmp_path, monkeypatch, argv, extra):
    monkeypatch.chdir(tmp_path)
    without("matplotlib", "can")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"admittance[{extra}]" in err
    assert not list(tmp_path.iterdir())  # nothing written


def test_the_can_reader_says_which_extra_it_needs(without):
    from admittance.drivers.can_sensor import CanForceReader
    from admittance.drivers.force_reader import SampleBuffer

    without("can")
    reader = CanForceReader("vcan0", 451.89, SampleBuffer())
    with pytest.raises(MissingExtra, match=r"admittance\[can\]"):
        reader.start()
