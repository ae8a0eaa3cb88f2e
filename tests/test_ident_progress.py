"""identify's progress: nothing in the first second, then one line per phase under a pipe and a
self-overwriting counter on a terminal (issue 19 item 2)."""

from __future__ import annotations

import io

from admittance.ident import identify


class _Stream(io.StringIO):
    def __init__(self, tty: bool):
        super().__init__()
        self._tty = tty

    def isatty(self) -> bool:
        return self._tty


def _progress(monkeypatch, tty: bool, elapsed: float):
    stream = _Stream(tty)
    monkeypatch.setattr(identify.sys, "stderr", stream)
    clock = iter([0.0] + [elapsed] * 100)
    monkeypatch.setattr(identify.time, "perf_counter", lambda: next(clock))
    return identify._Progress(quiet=False), stream


def test_nothing_is_shown_in_the_first_second(monkeypatch):
    progress, stream = _progress(monkeypatch, tty=False, elapsed=0.5)
    progress("base fit: iteration 1")
    assert stream.getvalue() == ""


def test_a_pipe_gets_one_plain_line_per_phase(monkeypatch):
    progress, stream = _progress(monkeypatch, tty=False, elapsed=2.0)
    for i in range(3):
        progress(f"base fit: iteration {i}")
    progress("effect search round 1: candidate 1/8 stribeck")
    lines = stream.getvalue().splitlines()
    assert lines == ["identify: base fit: iteration 0", "identify: effect search round 1: candidate 1/8 stribeck"]
    assert "\r" not in stream.getvalue()


def test_a_terminal_gets_one_counter_line_rewritten(monkeypatch):
    progress, stream = _progress(monkeypatch, tty=True, elapsed=2.0)
    progress("screening candidate 1/8 stribeck")
    progress("screening candidate 2/8 cogging")
    progress.done()
    text = stream.getvalue()
    assert "\n" not in text and text.count("\r") >= 3
    assert "candidate 2/8 cogging" in text


def test_the_command_shows_its_phases_under_a_pipe(monkeypatch, capsys, tmp_path):
    """`admittance identify` hands its progress to the phases: with the first second's silence
    taken out (a run can end within it), a pipe gets one plain line per phase."""
    from admittance.cli import main

    data = tmp_path / "ds"
    assert main(["synth", str(data), "--trials", "4", "--duration", "4", "--seed", "3"]) == 0
    capsys.readouterr()
    monkeypatch.setattr(identify._Progress, "QUIET_SECONDS", 0.0)
    assert main(["identify", str(data), "--json", str(tmp_path / "fit.json")]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("identify: ")]
    phases = [line.split(":")[1] for line in lines]
    assert len(lines) >= 2 and len(set(phases)) == len(phases), lines
