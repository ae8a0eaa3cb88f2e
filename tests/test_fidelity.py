"""`admittance fidelity`: the servo fit on servos its own simulator did not make, the
compensation it leads to, the contract's JSON and parameter file, and bad input.

The sessions here are written by a loop *oracle* (the virtual joint of Contract 1 and two servo
truths, plain Python written from their physics, not from the project's code) through the
daemon's own Recorder, so the recording has exactly the daemon's format:

- ``LagOracle``: a horn that lags its goal (exact exponential), read 0.3 ms after the write;
- ``BamOracle``: BAM's MX model: P-controlled PWM with the duty cap, DC motor with back-EMF,
  horn inertia, viscous and smooth (tanh) Coulomb friction, and the hand's torque on the horn.

The fit's own model is neither (it has an exact stick law, no duty cap, no tanh), so what it
recovers is what a recording shows, not what a shared simulator put in.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import tomli_w

from admittance.daemon.mcap_recording import McapRecorder
from admittance.daemon.recording import Recorder
from admittance.errors import DataError
from oracles import virtual_joint

RATE = 1000.0
H = 1.0 / RATE
SUBSTEPS = 10  # the truths run at 0.1 ms
TICK = 2 * math.pi / 4096
READ_AFTER = 3  # substeps: the present position is read 0.3 ms after the goal is written
VIRTUAL = (0.02, 0.1, 0.02)  # I, B, F of the joint the loop renders


def multisine(t: float) -> float:
    """A hand from 0.3 to 3 Hz (N·m)."""
    return 0.06 * math.sin(2 * math.pi * 0.3 * t) + 0.05 * math.sin(2 * math.pi * 0.9 * t + 1.0) \
        + 0.05 * math.sin(2 * math.pi * 1.7 * t + 2.0) + 0.06 * math.sin(2 * math.pi * 3.0 * t + 0.5)


class LagOracle:
    def __init__(self, time_constant=0.025):
        self.tc, self.theta = time_constant, 0.0

    def step(self, goal, tau, h):
        self.theta = goal + (self.theta - goal) * math.exp(-h / self.tc)


class BamOracle:
    """MX-64 at 12 V, P gain 850 (P2), kt 1.62, R 3.95; horn 0.0147 kg·m², B 0.035, F 0.084."""

    def __init__(self):
        self.theta = self.omega = 0.0
        self.kp_duty = 0.158 * 850 / 128 * 8
        self.inertia, self.damping, self.coulomb = 0.0147, 0.035, 0.084
        self.kt, self.r, self.vin = 1.62, 3.95, 12.0

    def step(self, goal, tau, h):
        duty = max(-0.9625, min(0.9625, self.kp_duty * (goal - self.theta)))
        motor = self.kt / self.r * (self.vin * duty - self.kt * self.omega)
        net = motor + tau - self.damping * self.omega - self.coulomb * math.tanh(self.omega / 0.01)
        self.omega += h * net / self.inertia
        self.theta += h * self.omega

    @property
    def stiffness(self):  # K: N·m per rad of error below the duty cap
        return self.kt / self.r * self.vin * self.kp_duty


def session(folder, servo, seconds=12.0, divisor=5, lead=None, hand=multisine):
    """Run the loop oracle against ``servo`` and record it with the daemon's Recorder. ``lead``
    (ω, α, τ) -> rad is the compensation. Returns the rendering error (RMS present − model)."""
    n = int(seconds * RATE)
    cols = {k: np.full(n, np.nan) for k in ("t", "t_wake", "tau", "force", "theta_model", "omega_model",
                                            "theta_goal", "theta_present", "cycle", "mode", "fault")}
    theta = omega = 0.0
    h = H / SUBSTEPS
    for k in range(n):
        t = k * H
        tau = hand(t)
        before = omega
        theta, omega = virtual_joint.step(theta, omega, tau, *VIRTUAL, H)
        goal = theta + (lead(omega, (omega - before) / H, tau) if lead else 0.0)
        goal = round(goal / TICK) * TICK
        read = None
        for j in range(SUBSTEPS):
            servo.step(goal, hand(t + j * h), h)
            if j == READ_AFTER - 1 and k % divisor == 0:
                read = round(servo.theta / TICK) * TICK
        for key, value in (("t", t), ("t_wake", t), ("tau", tau), ("force", tau / 0.1), ("theta_model", theta),
                           ("omega_model", omega), ("theta_goal", goal), ("cycle", k), ("mode", 0.0), ("fault", 0.0)):
            cols[key][k] = value
        cols["theta_present"][k] = np.nan if read is None else read
    info = {"model": "MX-64", "params_file": "mx64.toml", "rate_hz": RATE, "friction": "stick",
            "plant": {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084}}
    rec = Recorder(folder, [(1, "MX-64")], measured_theta=True, t0=0.0, segment_s=3.0, joint_info={1: info})
    params = {"1.virtual_inertia": VIRTUAL[0], "1.virtual_damping": VIRTUAL[1], "1.virtual_coulomb": VIRTUAL[2],
              "1.servo_compensation": 1.0 if lead else 0.0}
    rec.set_targets(params)
    mcap = McapRecorder(folder / "session.mcap", {"joints": [{**info, "id": 1, "name": "joint1"}], "t0": 0.0,
                                                  "segment_s": 3.0, "measured_theta": True, "rate_hz": RATE})
    mcap.params("start", params)
    for start in range(0, n, 97):  # drained in batches, as the supervisor does
        batch = {k: v[start:start + 97] for k, v in cols.items()}
        rec.append(1, batch)
        mcap.append(1, batch, wall_offset_ns=0)
    rec.close()
    mcap.close()
    read = ~np.isnan(cols["theta_present"])
    return float(np.sqrt(np.mean((cols["theta_present"][read] - cols["theta_model"][read]) ** 2)))


def fit_of(folder):
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.servo import fit_servo

    return fit_servo(load_recording(folder).of_joint(1))


def lead_of(fit):
    from admittance import _rtcore

    params = fit.params.copy()
    return lambda w, a, q: float(_rtcore.servo_lead(params, [w], [a], [q])[0])


@pytest.fixture(scope="module")
def lag_recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lag")
    return folder, session(folder, LagOracle())


@pytest.fixture(scope="module")
def bam_recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bam")
    return folder, session(folder, BamOracle())


def test_the_fit_recovers_a_first_order_lag_its_simulator_never_made(lag_recording):
    fit = fit_of(lag_recording[0])
    m = fit.model()
    # The read 0.3 ms after the write makes the horn look 0.3 ms less late than its lag.
    assert m["time_constant"] + m["dead_time"] == pytest.approx(0.025 - 0.0003, abs=0.001), m
    assert m["inertial_time"] < 0.002 and abs(m["compliance"]) < 0.005 and m["deadband"] < 0.0005, m
    assert fit.heldout and fit.heldout != fit.training
    assert fit.rmse_heldout < 0.7e-3, "the two tick quantisations' floor"
    assert fit.rmse_heldout < fit.baseline_heldout["goal"] / 10


def test_the_fit_captures_a_bam_style_servo_with_its_give_under_the_hand(bam_recording):
    fit = fit_of(bam_recording[0])
    m, truth = fit.model(), BamOracle()
    total_damping = truth.damping + truth.kt ** 2 / truth.r
    assert m["time_constant"] + m["dead_time"] == pytest.approx(total_damping / truth.stiffness, rel=0.15), m
    assert m["compliance"] == pytest.approx(1 / truth.stiffness, rel=0.25), m
    assert m["inertial_time"] == pytest.approx(truth.inertia / total_damping, rel=0.35), m
    assert fit.rmse_heldout < fit.baseline_heldout["goal"] / 5
    assert "summary" in fit.residual and fit.residual["rmse"] > 0


@pytest.mark.parametrize("truth", [LagOracle, BamOracle])
def test_compensating_with_the_fitted_model_cuts_the_rendering_error_3x(tmp_path, truth, lag_recording, bam_recording):
    folder, before = lag_recording if truth is LagOracle else bam_recording
    after = session(tmp_path, truth(), lead=lead_of(fit_of(folder)))
    assert after < before / 3, f"{1e3 * before:.2f} → {1e3 * after:.2f} mrad"


def test_the_cli_writes_the_contracts_json_and_a_params_file_that_turns_compensation_on(lag_recording, tmp_path):
    from admittance.cli import main
    from admittance.daemon.config import parse_config
    from admittance.formats import paramfile

    folder, rendering = lag_recording
    out, params = tmp_path / "f.json", tmp_path / "with_servo.toml"
    assert main(["fidelity", str(folder), "--json", str(out), "--params-out", str(params), "--quiet"]) == 0
    result = json.loads(out.read_text())
    assert result["rendering_rmse"] == pytest.approx(rendering, rel=0.05)
    assert result["target"] == dict(zip(("virtual_inertia", "virtual_damping", "virtual_coulomb"), VIRTUAL))
    assert set(result["rendered"]) >= {"virtual_inertia", "virtual_damping", "virtual_coulomb"}
    assert set(result["servo"]) >= {"time_constant", "inertial_time", "dead_time", "compliance", "deadband",
                                    "rmse_heldout", "residual"}
    for key, value in result["target_check"]["error"].items():  # record → identify on the model's own angle
        assert abs(value) < (0.05 if key == "virtual_coulomb" else 0.03), (key, value)
    written = paramfile.load(params)
    assert written["params"]["motor_inertia"] == 0.0147 and set(written["servo"]) == set(paramfile.SERVO_PARAM_NAMES)
    doc = {"bus": {"port": "/dev/null"}, "joints": [{"id": 1, "model": "MX-64", "params": str(params)}],
           "sensor": {"kind": "optoforce", "port": "/dev/null", "lever_arm": 0.1}}
    joint = parse_config(doc, tmp_path / "d.toml").joints[0]
    assert joint.servo_compensation == 1.0, "a [servo] model turns compensation on"
    doc["joints"][0]["servo_compensation"] = 0.0
    assert parse_config(doc, tmp_path / "d.toml").joints[0].servo_compensation == 0.0, "off by configuration"


def one_line_error(args, capsys) -> str:
    from admittance.cli import main

    assert main(args) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    return err


def test_bad_input_is_one_line_and_a_non_zero_exit(tmp_path, capsys, lag_recording):
    out = str(tmp_path / "f.json")
    assert "not found" in one_line_error(["fidelity", str(tmp_path / "absent"), "--json", out], capsys)
    from admittance.ident.synthetic import SynthSpec, generate  # a pendulum dataset: not a recording

    drops = tmp_path / "drops"
    generate(drops, SynthSpec(n_trials=3, duration=2.0))
    assert "not a recording" in one_line_error(["fidelity", str(drops), "--json", out], capsys)
    still = tmp_path / "still"
    session(still, LagOracle(), seconds=2.0, hand=lambda t: 0.0)
    assert "no hand torque" in one_line_error(["fidelity", str(still), "--json", out], capsys)
    manifest = lag_recording[0] / "manifest.toml"
    model_only = tmp_path / "model_only"
    model_only.mkdir()
    for f in lag_recording[0].iterdir():
        (model_only / f.name).write_bytes(f.read_bytes())
    (model_only / "manifest.toml").write_text(manifest.read_text().replace(
        'theta_source = "present position"', 'theta_source = "model angle (no present reads)"'))
    assert "no present positions" in one_line_error(["fidelity", str(model_only), "--json", out], capsys)


def test_holds_and_read_gaps_cut_the_segments(lag_recording):
    """A hold (stale force) and a 0.1 s hole in the reads each cut a segment; a stretch under 1 s
    between two cuts is dropped."""
    import dataclasses

    from admittance.fidelity.recording import MAX_GAP_S, _runs, load_recording

    segment = load_recording(lag_recording[0]).of_joint(1)[0]
    n = segment.n
    held = np.zeros(n)
    held[n // 4] = 1.0
    t = 2.0 * segment["t"]  # a 6 s segment: room for three stretches of more than 1 s
    keep = np.ones(n, bool)
    keep[n // 2: n // 2 + int(0.1 / np.median(np.diff(t)))] = False
    columns = {k: v[keep] for k, v in {**segment.columns, "held": held, "t": t}.items()}
    runs = _runs(dataclasses.replace(segment, columns=columns))
    assert len(runs) == 3 and all(r["held"].sum() == 0 for r in runs)
    assert all(np.diff(r["t"]).max() <= MAX_GAP_S for r in runs)
    assert sum(r.n for r in runs) == keep.sum() - 1


def test_the_session_mcap_gives_the_csv_folders_rows_targets_and_plant(lag_recording):
    """`fidelity` reads a session.mcap (every cycle) into the rows, targets and plant its CSV
    folder gives (the segments may be cut a few cycles apart: the CSV cuts at a drained batch)."""
    from admittance.fidelity.recording import load_recording

    folder = lag_recording[0]
    from_csv, from_mcap = load_recording(folder), load_recording(folder / "session.mcap")
    for column in ("t", "theta", "tau", "theta_model", "omega_model", "theta_goal", "t_wake", "cycle", "held"):
        a, b = (np.concatenate([s[column] for s in r.segments]) for r in (from_csv, from_mcap))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=column)
    assert {(tuple(s.target.items()), s.compensation) for s in from_mcap.segments} == \
        {(tuple(s.target.items()), s.compensation) for s in from_csv.segments} == \
        {(tuple(zip(("virtual_inertia", "virtual_damping", "virtual_coulomb"), VIRTUAL)), 0.0)}
    assert from_mcap.joints[1]["plant"] == from_csv.joints[1]["plant"]


def test_a_recording_without_present_columns_is_refused(tmp_path):
    from admittance.fidelity.recording import load_recording

    (tmp_path / "manifest.toml").write_text(tomli_w.dumps({
        "theta_source": "present position", "bob": {"mass": 1e-6},
        "trials": [{"file": "a.csv", "bob_distance": 1e-3}]}))
    (tmp_path / "a.csv").write_text("t,theta,tau\n" + "".join(f"{i * 0.01},0,0.1\n" for i in range(20)))
    with pytest.raises(DataError, match="no column theta_model"):
        load_recording(tmp_path)
