"""The foreign-format trial loaders and the contract-dataset converter."""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from admittance.errors import DataError
from admittance.formats.converters import ConvertedTrial, convert_files, load_trial, parse_motive, trial_names, write_dataset

from helpers import examples


def motive_csv(path, t, axis_xyz, bob_xyz, *, rigid_body=False, timecode=False, names=("Pend:Axis", "Pend:Bob")):
    """A Motive 1.23-style export; a None row in a marker array leaves its cells blank."""
    pad = 3 if timecode else 2
    cols_type, cols_name, cols_comp, cols_axis = [], [], [], []
    if rigid_body:  # a rigid body (rotation quaternion + position) before the markers
        cols_type += ["Rigid Body"] * 7
        cols_name += ["Pend"] * 7
        cols_comp += ["Rotation"] * 4 + ["Position"] * 3
        cols_axis += ["X", "Y", "Z", "W", "X", "Y", "Z"]
    for name in names:
        cols_type += ["Marker"] * 3
        cols_name += [name] * 3
        cols_comp += ["Position"] * 3
        cols_axis += ["X", "Y", "Z"]
    def labelled(label, cells):
        return ",".join(["", label] + [""] * (pad - 2) + cells)

    lines = [
        "Format Version,1.23,Take Name,drop,Capture Frame Rate,120.000000,Length Units,Meters",
        "",
        labelled("Type", cols_type),
        labelled("Name", cols_name),
        labelled("ID", ["1"] * len(cols_type)),
        ",".join([""] * pad + cols_comp),
        ",".join(["Frame", "Time (Seconds)"] + (["TimeCode"] if timecode else []) + cols_axis),
    ]
    for k, tk in enumerate(t):
        cells = [str(k), f"{tk:.6f}"] + (["00:00:00:01.00"] if timecode else [])
        if rigid_body:
            cells += ["0", "0", "0", "1", "0.1", "0.2", "0.3"]
        for arr in (axis_xyz, bob_xyz):
            cells += [""] * 3 if arr[k] is None else [f"{v:.9f}" for v in arr[k]]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def swing(theta, radius=0.3, origin=(0.05, 1.2, -0.4)):
    """Marker positions for angles theta, in the thesis's x–z plane (x along the hanging rod)."""
    axis = [tuple(origin)] * len(theta)
    bob = [(origin[0] + radius * math.cos(a), origin[1], origin[2] + radius * math.sin(a)) for a in theta]
    return axis, bob


def test_motive_angle_and_time(tmp_path):
    t = np.arange(240) / 120.0
    theta = 1.5 * np.exp(-0.3 * t) * np.cos(2 * math.pi * 0.9 * t)
    axis, bob = swing(theta)
    path = motive_csv(tmp_path / "drop.csv", t, axis, bob)
    tt, th, tau = load_trial(path, "motive")
    assert tau is None
    np.testing.assert_allclose(tt, np.round(t, 6))
    np.testing.assert_allclose(th, theta, atol=1e-7)


@pytest.mark.parametrize("rigid_body,timecode", [(True, False), (False, True), (True, True)])
def test_motive_skips_rotations_and_timecode(tmp_path, rigid_body, timecode):
    t = np.arange(50) / 120.0
    theta = np.linspace(-1.0, 1.0, 50)
    axis, bob = swing(theta)
    path = motive_csv(tmp_path / "d.csv", t, axis, bob, rigid_body=rigid_body, timecode=timecode)
    take = parse_motive(path)
    assert take.labels[-2:] == ["Pend:Axis", "Pend:Bob"]
    _, th, _ = load_trial(path, "motive")  # default: the two points of type Marker
    np.testing.assert_allclose(th, theta, atol=1e-7)


def test_motive_blank_cells_drop_the_frame(tmp_path):
    t = np.arange(30) / 120.0
    theta = np.linspace(0.2, 0.8, 30)
    axis, bob = swing(theta)
    bob[4] = None
    axis[17] = None
    path = motive_csv(tmp_path / "gaps.csv", t, axis, bob)
    tt, th, _ = load_trial(path, "motive")
    keep = np.ones(30, bool)
    keep[[4, 17]] = False
    np.testing.assert_allclose(tt, np.round(t[keep], 6))
    np.testing.assert_allclose(th, theta[keep], atol=1e-7)


def test_motive_options_axes_sign_offset_and_names(tmp_path):
    t = np.arange(20) / 120.0
    theta = np.linspace(-0.5, 0.5, 20)
    axis, bob = swing(theta)
    path = motive_csv(tmp_path / "o.csv", t, axis, bob)
    _, th, _ = load_trial(path, "motive", markers=["Pend:Axis", "Pend:Bob"], sign=-1.0, offset=0.1)
    np.testing.assert_allclose(th, -theta - 0.1, atol=1e-7)
    _, swapped, _ = load_trial(path, "motive", axes=("z", "x"))
    np.testing.assert_allclose(swapped, np.pi / 2 - theta, atol=1e-7)


def test_motive_angle_is_unwrapped_through_pi(tmp_path):
    t = np.arange(100) / 120.0
    theta = np.linspace(2.5, 3.8, 100)  # crosses +π, where atan2 jumps to −π
    axis, bob = swing(theta)
    _, th, _ = load_trial(motive_csv(tmp_path / "w.csv", t, axis, bob), "motive")
    np.testing.assert_allclose(th, theta, atol=1e-7)


@settings(max_examples=examples(25), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    angles=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=40),
    radius=st.floats(0.05, 2.0),
    origin=st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5)),
    dt=st.floats(0.001, 0.05),
)
def test_motive_parser_recovers_generated_angles(tmp_path_factory, angles, radius, origin, dt):
    theta = np.unwrap(np.asarray(angles))
    t = np.arange(len(theta)) * dt
    axis, bob = swing(theta, radius, origin)
    path = motive_csv(tmp_path_factory.mktemp("m") / "h.csv", t, axis, bob)
    _, th, _ = load_trial(path, "motive")
    # the angle is defined up to a whole turn at the start; its increments are exact
    shift = th[0] - theta[0]
    assert abs(shift - 2 * math.pi * round(shift / (2 * math.pi))) < 1e-6
    np.testing.assert_allclose(np.diff(th), np.diff(theta), atol=1e-6)


def test_motive_errors(tmp_path):
    plain = tmp_path / "plain.csv"
    plain.write_text("a,b\n1,2\n")
    with pytest.raises(DataError, match="not a Motive"):
        load_trial(plain, "motive")
    t = np.arange(10) / 120.0
    axis, bob = swing(np.zeros(10))
    path = motive_csv(tmp_path / "ok.csv", t, axis, bob)
    with pytest.raises(DataError, match="no marker"):
        load_trial(path, "motive", markers=["Pend:Axis", "Nope"])
    with pytest.raises(DataError, match="axes"):
        load_trial(path, "motive", axes=("x", "x"))
    with pytest.raises(DataError, match="bad option"):
        load_trial(path, "motive", colour="red")
    bob = [None] * 10
    with pytest.raises(DataError, match="both markers"):
        load_trial(motive_csv(tmp_path / "hidden.csv", t, axis, bob), "motive")


def test_motive_non_increasing_time_is_an_error(tmp_path):
    t = np.array([0.0, 0.01, 0.01, 0.02])
    axis, bob = swing(np.zeros(4))
    with pytest.raises(DataError, match="strictly increasing"):
        load_trial(motive_csv(tmp_path / "t.csv", t, axis, bob), "motive")


def bam_json(path, t, q, enabled):
    entries = [
        {"timestamp": float(a), "position": float(b), "speed": 0.0, "load": 0, "torque_enable": bool(c)}
        for a, b, c in zip(t, q, enabled)
    ]
    path.write_text(json.dumps({"mass": 0.49, "length": 0.1, "kp": 100, "entries": entries}))
    return path


def test_bam_json_torque_off_segment(tmp_path):
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.003, 0.006, 400))  # non-uniform, like the real logs
    q = np.sin(t)
    enabled = t < t[150]
    path = bam_json(tmp_path / "swing.json", t, q, enabled)
    tt, th, tau = load_trial(path, "dynamixel")
    assert tau is None
    assert tt[0] == 0.0
    np.testing.assert_allclose(tt, t[150:] - t[150])
    np.testing.assert_allclose(th, q[150:])
    tt, th, _ = load_trial(path, "dynamixel", segment="all")
    assert len(tt) == 400


def test_bam_json_errors(tmp_path):
    t = np.arange(10) * 0.005
    with pytest.raises(DataError, match="never disabled"):
        load_trial(bam_json(tmp_path / "on.json", t, t, [True] * 10), "dynamixel")
    with pytest.raises(DataError, match="re-enabled"):
        load_trial(bam_json(tmp_path / "re.json", t, t, [True, False] * 5), "dynamixel")
    with pytest.raises(DataError, match="segment"):
        load_trial(bam_json(tmp_path / "s.json", t, t, [False] * 10), "dynamixel", segment="half")
    bad = tmp_path / "bad.json"
    bad.write_text('{"entries": [{"time": 1}]}')
    with pytest.raises(DataError, match="not a BAM log"):
        load_trial(bad, "dynamixel")


def test_tick_csv(tmp_path):
    path = tmp_path / "ticks.csv"
    path.write_text("time,present_position\n0.0,2048\n0.01,3072\n0.025,1024\n0.03,2047\n")
    t, th, tau = load_trial(path, "dynamixel")
    np.testing.assert_allclose(t, [0.0, 0.01, 0.025, 0.03])
    np.testing.assert_allclose(th, [0.0, math.pi / 2, -math.pi / 2, -2 * math.pi / 4096])
    assert tau is None
    _, th, _ = load_trial(path, "dynamixel", zero_tick=1024, sign=-1)
    np.testing.assert_allclose(th[0], -math.pi / 2)


@pytest.mark.parametrize("text,match", [
    ("time,speed\n0,1\n1,2\n2,3\n", "missing column"),
    ("t,ticks\n0,1\n1\n2,3\n", "row 2"),
    ("t,ticks\n0,1\n1,\n2,3\n", "NaN"),
    ("t,ticks\n0,1\n1,x\n2,3\n", "non-numeric"),
])
def test_tick_csv_errors(tmp_path, text, match):
    path = tmp_path / "ticks.csv"
    path.write_text(text)
    with pytest.raises(DataError, match=match):
        load_trial(path, "dynamixel")


def test_dfki_csv(tmp_path):
    path = tmp_path / "data_measured.csv"
    path.write_text("time,position,velocity,torque\n0,0.1,0,0.5\n0.0033,0.11,3,0.4\n0.0071,0.12,3,-0.2\n")
    t, th, tau = load_trial(path, "dfki")
    np.testing.assert_allclose(t, [0, 0.0033, 0.0071])
    np.testing.assert_allclose(th, [0.1, 0.11, 0.12])
    np.testing.assert_allclose(tau, [0.5, 0.4, -0.2])
    assert load_trial(path, "dfki", torque=False)[2] is None


def test_unknown_format_and_missing_file(tmp_path):
    with pytest.raises(DataError, match="unknown trial format"):
        load_trial(tmp_path / "x.csv", "vicon")
    with pytest.raises(DataError, match="not found"):
        load_trial(tmp_path / "x.csv", "dfki")


def test_write_dataset_round_trip(tmp_path):
    t = np.linspace(0, 1, 11)
    trials = [
        ConvertedTrial("free", t, np.cos(t), None, {"bob_distance": 0.1}),
        ConvertedTrial("driven", t, np.sin(t), 0.1 * t),
    ]
    out = write_dataset(tmp_path / "ds", trials, {"motor": "XL330", "bob": {"mass": 0.49}})
    manifest = tomllib.loads((out / "manifest.toml").read_text())
    assert manifest["motor"] == "XL330" and manifest["bob"]["mass"] == 0.49
    assert [e["file"] for e in manifest["trials"]] == ["free.csv", "driven.csv"]
    assert manifest["trials"][0]["bob_distance"] == 0.1
    free = np.genfromtxt(out / "free.csv", delimiter=",", names=True)
    assert free.dtype.names == ("t", "theta")
    np.testing.assert_allclose(free["theta"], np.cos(t), rtol=1e-8)
    driven = np.genfromtxt(out / "driven.csv", delimiter=",", names=True)
    np.testing.assert_allclose(driven["tau"], 0.1 * t, atol=1e-9)


def test_convert_files_and_bad_trial_writes_nothing(tmp_path):
    src = tmp_path / "a.csv"
    src.write_text("time,position,velocity,torque\n0,0,0,0\n0.1,0.1,1,0.2\n0.2,0.2,1,0.1\n")
    out = convert_files([src], "dfki", tmp_path / "ds", header={"motor": "AK80-6"})
    assert (out / "a.csv").is_file()
    with pytest.raises(DataError):
        write_dataset(tmp_path / "bad", [ConvertedTrial("x", [0, 1, 1], [0, 0, 0])])
    assert not (tmp_path / "bad" / "manifest.toml").exists()


def test_window_and_subsampling_options(tmp_path):
    path = tmp_path / "data_measured.csv"
    rows = "\n".join(f"{0.01 * k},{0.1 * k},0,{k}" for k in range(100))
    path.write_text("time,position,velocity,torque\n" + rows + "\n")
    t, th, tau = load_trial(path, "dfki", t_start=0.2, t_stop=0.5, every=2)
    np.testing.assert_allclose(t, 0.01 * np.arange(20, 51, 2))
    np.testing.assert_allclose(tau, np.arange(20, 51, 2))
    with pytest.raises(DataError, match="every"):
        load_trial(path, "dfki", every=0)
    with pytest.raises(DataError, match="usable samples"):
        load_trial(path, "dfki", t_start=5.0)


def test_trial_names_disambiguate_repeated_stems(tmp_path):
    names = trial_names([tmp_path / "pd" / "data_measured.csv", tmp_path / "ddp" / "data_measured.csv",
                         tmp_path / "other.csv"])
    assert names == ["pd_data_measured", "ddp_data_measured", "other"]
    with pytest.raises(DataError, match="same trial name"):
        trial_names([tmp_path / "a" / "x.csv", tmp_path / "a" / "x.json"])


def test_convert_cli_writes_a_geometry_dataset(tmp_path, capsys):
    from admittance.cli import main

    src = tmp_path / "run" / "data_measured.csv"
    src.parent.mkdir()
    rows = "\n".join(f"{0.01 * k},{0.1 * k},0,{k}" for k in range(50))
    src.write_text("time,position,velocity,torque\n" + rows + "\n")
    out = tmp_path / "ds"
    argv = ["convert", "dfki", str(src), "--out", str(out), "--motor", "AK80-6", "--bob", "0.546", "0.5",
            "--rod", "0.13", "0.5", "--option", "t_stop=0.2"]
    assert main(argv) == 0
    assert "wrote 1 trial" in capsys.readouterr().out
    manifest = tomllib.loads((out / "manifest.toml").read_text())
    assert manifest["bob"] == {"mass": 0.546} and manifest["rod"] == {"mass": 0.13, "length": 0.5}
    assert manifest["trials"] == [{"file": "data_measured.csv", "bob_distance": 0.5}]
    assert main(["convert", "dfki", str(src), "--out", str(out), "--option", "colour"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err
    bad_geometry = tmp_path / "bad"
    assert main(["convert", "dfki", str(src), "--out", str(bad_geometry), "--bob", "-0.5", "0.5"]) == 2
    assert "--bob" in capsys.readouterr().err and not bad_geometry.exists()


def test_dataset_loader_dispatches_trial_formats(tmp_path):
    from admittance.formats.dataset import load_dataset

    t = np.arange(60) * 0.005
    bam_json(tmp_path / "drop.json", t, np.cos(t), t < 0.05)
    (tmp_path / "manifest.toml").write_text(
        'motor = "XL330"\n[bob]\nmass = 0.49\n'
        '[[trials]]\nfile = "drop.json"\nformat = "dynamixel"\nbob_distance = 0.1\n')
    (trial,) = load_dataset(tmp_path).trials
    assert trial.t[0] == 0.0 and trial.n_samples == 50
    np.testing.assert_allclose(trial.theta, np.cos(t[10:]))
    assert trial.gravity_torque == pytest.approx(0.49 * 9.80665 * 0.1)
