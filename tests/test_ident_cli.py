"""``admittance identify`` and ``admittance synth`` from the command line: outputs, exit codes,
and one-line errors on every kind of bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from admittance.cli import main
from admittance.formats import paramfile


def _run(*args):
    return subprocess.run([sys.executable, "-m", "admittance", *args], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "ds"
    assert main(["synth", str(out), "--trials", "4", "--duration", "4", "--seed", "3",
                 "--effect", "angle_offset=0.03"]) == 0
    return out


def test_identify_writes_json_params_and_report(synth_dir, tmp_path):
    out_json = tmp_path / "out.json"
    params = tmp_path / "p.toml"
    report = tmp_path / "report"
    proc = _run("identify", str(synth_dir), "--json", str(out_json), "--params-out", str(params),
                "--report", str(report))
    assert proc.returncode == 0, proc.stderr
    j = json.loads(out_json.read_text())
    assert j["effects"] == ["angle_offset"]
    assert j["params"]["angle_offset"] == pytest.approx(0.03, abs=0.003)
    doc = paramfile.load(params)
    assert doc["model"]["mode"] == "geometry" and doc["fit"]["effects"] == ["angle_offset"]
    assert doc["params"]["motor_inertia"] == pytest.approx(j["motor_inertia"])
    text = (report / "report.md").read_text()
    assert "angle_offset" in text
    for line in text.splitlines():
        if line.startswith("!["):
            assert (report / line.split("(")[1].rstrip(")")).is_file()
    # The progress lines (shown after the first second) are wired in
    # test_ident_progress.test_the_command_shows_its_phases_under_a_pipe: this run can end within it.


def test_quiet_and_max_effects_zero(synth_dir, tmp_path):
    out_json = tmp_path / "out.json"
    proc = _run("identify", str(synth_dir), "--json", str(out_json), "--quiet", "--max-effects", "0",
                "--friction", "tanh")
    assert proc.returncode == 0 and proc.stderr == ""
    j = json.loads(out_json.read_text())
    assert j["effects"] == [] and j["friction"] == "tanh"


def _bad_dataset(tmp_path, manifest, csv):
    (tmp_path / "manifest.toml").write_text(manifest)
    if csv is not None:
        (tmp_path / "a.csv").write_text(csv)
    return tmp_path


GOOD_CSV = "t,theta\n" + "".join(f"{0.01 * i},{0.5 - 0.001 * i}\n" for i in range(30))


@pytest.mark.parametrize(
    "manifest, csv, fragment",
    [
        ('[[trials]]\nfile = "a.csv"\n', None, "trial file not found"),
        ('[[trials]]\nfile = "a.csv"\n', GOOD_CSV.replace("theta", "angle"), "missing column 'theta'"),
        ('[[trials]]\nfile = "a.csv"\n', GOOD_CSV.replace("0.02,", "0.005,"), "not strictly increasing"),
        ('[[trials]]\nfile = "a.csv"\n', GOOD_CSV.replace("0.03,0.497", "0.03,nan"), "NaN"),
        ('[[trials]]\nfile = "a.csv"\n', "t,theta\n", "empty trial"),
        ("[bob]\nmass = 0.1\n[[trials]]\nfile = \"a.csv\"\n", GOOD_CSV, "bob_distance"),
    ],
)
def test_bad_input_gives_one_line_and_nonzero_exit(tmp_path, manifest, csv, fragment):
    folder = _bad_dataset(tmp_path, manifest, csv)
    proc = _run("identify", str(folder), "--json", str(tmp_path / "o.json"))
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "o.json").exists()


def test_missing_dataset_and_bad_options(tmp_path, capsys):
    assert main(["identify", str(tmp_path / "none"), "--json", str(tmp_path / "o.json")]) != 0
    assert "dataset folder not found" in capsys.readouterr().err
    assert main(["identify", str(tmp_path), "--json", str(tmp_path / "no" / "o.json")]) != 0
    assert "does not exist" in capsys.readouterr().err
    assert main(["identify", str(tmp_path), "--json", str(tmp_path)]) != 0
    assert "is a folder" in capsys.readouterr().err
    (tmp_path / "taken").write_text("")
    assert main(["identify", str(tmp_path), "--json", str(tmp_path / "o.json"), "--report", str(tmp_path / "taken")]) != 0
    assert "not a folder" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "s"), "--effect", "wobble=1"]) != 0
    assert "unknown effect" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "s"), "--effect", "stribeck"]) != 0
    assert "NAME=NUMBER" in capsys.readouterr().err
    for option, value in (("--duration", "nan"), ("--duration", "inf"), ("--noise", "nan"), ("--jitter", "-1")):
        assert main(["synth", str(tmp_path / "s"), option, value]) != 0
        assert option in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_synth_with_torque_writes_a_tau_column(tmp_path):
    out = tmp_path / "ds"
    assert main(["synth", str(out), "--trials", "2", "--duration", "2", "--with-torque", "--lumped"]) == 0
    first = sorted(out.glob("*.csv"))[0].read_text().splitlines()[0]
    assert first == "t,theta,tau"
    assert "[rod]" not in (out / "manifest.toml").read_text()
    truth = json.loads((out / "truth.json").read_text())
    assert len({trial["bob_distance"] for trial in truth["trials"]}) == 1  # lumped: one load
    assert truth["params"]["motor_inertia"] == pytest.approx(0.0147)
