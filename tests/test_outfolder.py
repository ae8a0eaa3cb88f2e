"""Commands that write a folder refuse a non-empty one unless --force, and with --force never
leave old trials beside the new manifest."""

from __future__ import annotations

import pytest

from admittance.cli import main
from admittance.formats.dataset import load_dataset


def _synth(folder, *extra):
    return main(["synth", str(folder), "--trials", "2", "--duration", "2", *extra])


def test_synth_refuses_a_non_empty_folder_and_force_replaces_the_old_trials(tmp_path, capsys):
    out = tmp_path / "ds"
    assert _synth(out) == 0
    (out / "stale_trial.csv").write_text("t,theta\n0,0\n")
    (out / "notes.txt").write_text("mine")
    assert _synth(out) == 2
    assert "not empty" in capsys.readouterr().err and (out / "stale_trial.csv").exists()
    assert _synth(out, "--force") == 0
    assert not (out / "stale_trial.csv").exists() and (out / "notes.txt").read_text() == "mine"
    assert len(load_dataset(out).trials) == 2


def test_convert_with_bad_input_leaves_the_folder_as_it_was(tmp_path):
    out = tmp_path / "ds"
    assert _synth(out) == 0
    before = sorted(p.name for p in out.iterdir())
    bad = tmp_path / "bad.csv"
    bad.write_text("not a motive file\n")
    assert main(["convert", "motive", str(bad), "--out", str(out), "--force"]) != 0
    assert sorted(p.name for p in out.iterdir()) == before


def test_run_record_refuses_a_non_empty_folder_before_starting(tmp_path, capsys):
    (tmp_path / "old.csv").write_text("t\n")
    assert main(["run", "--record", str(tmp_path), "--duration", "1"]) == 2
    assert "--force" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["predict", "DS", "--params", "p.toml", "--out", "OUT"],
                                  ["identify", "DS", "--json", "x.json", "--report", "OUT"]])
def test_report_folders_refuse_before_any_work(tmp_path, capsys, argv):
    (tmp_path / "OUT").mkdir()
    (tmp_path / "OUT" / "old.png").write_bytes(b"")
    argv = [str(tmp_path / a) if a in ("DS", "OUT") else a for a in argv]
    assert main(argv) == 2
    assert "not empty" in capsys.readouterr().err
