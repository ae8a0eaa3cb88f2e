"""`admittance fidelity`: the servo fit on servos its own simulator did not make, the
compensation it leads to, the verdict that decides whether the loop uses it, the contract's
JSON and parameter file, and bad input.

The sessions here are written by a loop *oracle* (tests/oracles/servo.py: the virtual joint of
Contract 1 and servo truths, plain Python written from their physics, not from the project's
code) through the daemon's own Recorder, so the recording has exactly the daemon's format. The
fit's own model is none of the truths (it has an exact stick law, no duty cap, no tanh, no
backlash, no speed limit), so what it recovers is what a recording shows, not what a shared
simulator put in.
"""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import tomli_w

from oracles.servo import RATE, TICK, VIRTUAL, BamOracle, LagOracle, multisine, session  # noqa: F401
from admittance.errors import DataError
from oracles import virtual_joint

def fit_of(folder):
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.servo import fit_servo

    return fit_servo(load_recording(folder).of_joint(1))


def lead_of(fit):
    from admittance import _rtcore

    params = fit.params.copy()
    return lambda w, a, q: _rtcore.servo_lead(params, w, a, q, h=1.0 / RATE)


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


def test_the_gear_play_is_fitted_where_the_data_show_it_and_left_out_where_they_do_not(bam_recording, tmp_path):
    from oracles.servo import GearedOracle

    truth = GearedOracle()
    off = session(tmp_path / "geared", truth)
    fit = fit_of(tmp_path / "geared")
    m = fit.model()
    assert m["backlash"] == pytest.approx(truth.play, rel=0.1), m
    assert m["backlash_torque"] == pytest.approx(truth.free, rel=0.25), m
    told = [n for n in fit.notes if n.startswith("gear backlash")]
    assert len(told) == 1 and "admitted" in told[0] and "without the play" in told[0], fit.notes
    # The play's inverse in the lead (the cycles in order): the target, ≥ 5× on a geared servo
    # (measured 5.5×; 3.0× when the side followed the present torque over a fixed 5 ms ramp).
    on = session(tmp_path / "geared-on", GearedOracle(), lead=lead_of(fit))
    assert on < off / 5, f"{1e3 * off:.2f} → {1e3 * on:.2f} mrad"
    # A servo without play: the play's fit does not cut the held-out error, so it stays 0.
    rigid = fit_of(bam_recording[0])
    assert rigid.model()["backlash"] == 0.0 and rigid.model()["backlash_torque"] == 0.0
    assert any(n.startswith("no gear backlash: held-out error") for n in rigid.notes), rigid.notes


def test_a_wide_play_is_crossed_on_the_side_decided_for_a_free_or_a_held_horn(tmp_path):
    # A 1° play under the multi-sine hand: 4.0× when the side was decided half a crossing ahead
    # whatever the horn's state; 5.0× deciding into a free horn only as early as the reference runs
    # away from it and into a held one a whole crossing ahead; 5.5× deciding into a held one where
    # the error before and after the hand takes hold is least (held_lead; bench/servo_forms.py).
    import math

    from oracles.servo import GearedOracle

    off = session(tmp_path / "off", GearedOracle(backlash=math.radians(1.0)))
    fit = fit_of(tmp_path / "off")
    assert fit.model()["backlash"] == pytest.approx(math.radians(1.0), rel=0.1), fit.model()
    on = session(tmp_path / "on", GearedOracle(backlash=math.radians(1.0)), lead=lead_of(fit))
    assert on < off / 5.2, f"{1e3 * off:.2f} → {1e3 * on:.2f} mrad"


def test_a_small_play_does_not_leave_the_fit_in_the_lag_form_s_dead_time_valley(tmp_path):
    # A 0.25° play: the lag form alone trades the motor's lag for a dead time (T 3.6 ms, 12 ms),
    # and LM with the play from there stays in that valley (T 4.2 ± 1.9 ms: refused, unpinned).
    import math

    from oracles.servo import GearedOracle

    truth = GearedOracle(backlash=math.radians(0.25))
    session(tmp_path, truth)
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.report import analyse

    result = analyse(load_recording(tmp_path))
    m = result["servo"]
    total_damping = truth.damping + truth.kt ** 2 / truth.r
    assert m["time_constant"] + m["dead_time"] == pytest.approx(total_damping / truth.stiffness, rel=0.15), m
    assert m["backlash"] == pytest.approx(truth.play, rel=0.1), m
    assert result["servo_verdict"]["passed"], result["servo_verdict"]


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
    short = {k: v[: int(0.5 / np.median(np.diff(t)))] for k, v in {**segment.columns, "t": t}.items()}
    assert _runs(dataclasses.replace(segment, columns=short)) == [], "an uncut segment under MIN_RUN_S is dropped too"


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


# -- the gates between a servo fit and the loop's compensation --------------------------------------


@pytest.fixture(scope="module")
def slew_recording(tmp_path_factory):
    from oracles.servo import SlewOracle

    folder = tmp_path_factory.mktemp("slew")
    return folder, session(folder, SlewOracle())


def _cli_params(folder, tmp_path):
    """`fidelity --params-out` on ``folder``: (its JSON, the servo_compensation a joint naming
    the written file gets by default)."""
    from admittance.cli import main
    from admittance.daemon.config import parse_config

    out, params = tmp_path / "f.json", tmp_path / "servo.toml"
    assert main(["fidelity", str(folder), "--json", str(out), "--params-out", str(params), "--quiet"]) == 0
    doc = {"bus": {"port": "/dev/null"}, "joints": [{"id": 1, "model": "MX-64", "params": str(params)}],
           "sensor": {"kind": "optoforce", "port": "/dev/null", "lever_arm": 0.1}}
    return json.loads(out.read_text()), parse_config(doc, tmp_path / "d.toml").joints[0].servo_compensation


def test_a_fit_that_describes_the_servo_passes_and_turns_compensation_on(lag_recording, tmp_path):
    result, compensation = _cli_params(lag_recording[0], tmp_path)
    assert result["servo_verdict"]["passed"] is True and result["servo_verdict"]["reasons"] == []
    assert compensation == 1.0
    assert result["target_check"]["verdict"]["passed"] is True


def test_a_servo_the_form_does_not_describe_is_refused_and_written_with_compensation_off(slew_recording, tmp_path,
                                                                                       capsys):
    from admittance.cli import main

    result, compensation = _cli_params(slew_recording[0], tmp_path)
    verdict = result["servo_verdict"]
    assert verdict["passed"] is False and verdict["reasons"], verdict
    assert compensation == 0.0, "a refused fit never turns compensation on by default"
    assert any("misses an effect" in n for n in result["servo"]["notes"]), result["servo"]["notes"]
    assert main(["fidelity", str(slew_recording[0]), "--json", str(tmp_path / "g.json")]) == 0
    line = capsys.readouterr().err
    assert "refused, compensation off" in line and "misses an effect" in line, line


@pytest.mark.parametrize("broken", ["heldout_gain", "no_heldout", "nan_heldout", "over_noise", "sigma"])
def test_each_criterion_of_the_verdict_refuses_on_its_own(broken):
    from admittance.fidelity.judge import MAX_OVER_NOISE, MIN_HELDOUT_GAIN, judge

    good = dict(rmse_heldout=1e-4, baseline={"goal": 1e-2, "model": 1e-2}, residual={"rmse_over_noise": 1.0},
                params={"time_constant": 0.02}, sigma={"time_constant": 1e-4, "dead_time": 1e-5})
    assert judge(**good).passed
    bad = {"heldout_gain": dict(rmse_heldout=1.01e-2 / MIN_HELDOUT_GAIN),
           # no held-out row scored: the empty mean's 0 (and baselines of 0) is no evidence
           "no_heldout": dict(rmse_heldout=0.0, baseline={"goal": 0.0, "model": 0.0}),
           "nan_heldout": dict(rmse_heldout=math.nan),
           "over_noise": dict(residual={"rmse_over_noise": MAX_OVER_NOISE * 1.01}),
           "sigma": dict(sigma={"time_constant": 0.01, "dead_time": 1e-5})}[broken]
    verdict = judge(**{**good, **bad})
    assert not verdict.passed and len(verdict.reasons) == 1, verdict


def test_a_coloured_residual_near_the_floor_is_noted_not_refused():
    from admittance.fidelity.judge import judge, misfit_note

    residual = {"rmse_over_noise": 1.45, "white": False, "ljung_box_p": 1e-40}
    assert judge(1e-4, {"goal": 1e-2, "model": 1e-2}, residual, {"time_constant": 0.02},
                 {"time_constant": 1e-4}).passed
    assert "misses an effect" in misfit_note(residual)
    assert misfit_note({**residual, "white": True}) is None and misfit_note({**residual, "rmse_over_noise": 1.1}) is None


def test_the_held_out_segments_are_scored_and_never_fitted(lag_recording):
    """Corrupting the held-out segments leaves the fitted model as it is and shows in the
    held-out error only: the split is real, in both directions."""
    import dataclasses

    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.servo import fit_servo, split

    segments = load_recording(lag_recording[0]).of_joint(1)
    held, _ = split(segments)
    clean = fit_servo(segments)
    noisy = list(segments)
    rng = np.random.default_rng(1)
    for i in held:
        columns = {**segments[i].columns, "theta": segments[i]["theta"] + rng.normal(0, 0.01, segments[i].n)}
        noisy[i] = dataclasses.replace(segments[i], columns=columns)
    corrupted = fit_servo(noisy)
    np.testing.assert_array_equal(corrupted.params, clean.params)
    assert corrupted.rmse_training == clean.rmse_training
    assert corrupted.rmse_heldout > 10 * clean.rmse_heldout


def test_a_signed_parameter_the_data_do_not_pin_is_fixed_at_zero(lag_recording):
    """The lag servo has no give under the hand: its compliance is within 2 σ of 0, fixed there
    and said so (without the rule the fit trades it against the lag)."""
    fit = fit_of(lag_recording[0])
    assert fit.model()["compliance"] == 0.0 and fit.sigma[3] == 0.0
    assert any(n.startswith("compliance") and "fixed at 0" in n for n in fit.notes), fit.notes


def test_segments_with_a_live_change_are_left_out_of_the_analysis(lag_recording, tmp_path):
    import tomllib

    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.report import analyse

    folder = tmp_path / "changed"
    shutil.copytree(lag_recording[0], folder)
    manifest = tomllib.loads((folder / "manifest.toml").read_text())
    manifest["trials"][0]["params_changed"] = True
    (folder / "manifest.toml").write_text(tomli_w.dumps(manifest))
    result = analyse(load_recording(folder))
    changed = manifest["trials"][0]["file"]
    assert any(name.startswith(changed) for name in result["excluded_segments"])
    assert not any(name.startswith(changed) for name in result["segments"])


def test_the_target_check_fails_when_identify_misses_the_target():
    from admittance.fidelity.report import target_check_verdict

    source = "recording manifest (what the loop ran)"
    assert target_check_verdict({"virtual_inertia": 0.01, "virtual_damping": -0.02, "virtual_coulomb": 0.04},
                                source)["passed"] is True
    failed = target_check_verdict({"virtual_inertia": 0.18, "virtual_damping": 0.0, "virtual_coulomb": None}, source)
    assert failed["passed"] is False and "virtual_inertia off by +18.0 %" in failed["reasons"][0]
    assert target_check_verdict({"virtual_inertia": 0.5}, "identify on theta_model")["passed"] is None


def test_the_loops_fallback_is_told_once_in_a_line(tmp_path):
    from admittance.daemon.faults import FaultWatch

    from test_daemon_supervisor import FakeLoop, Harness

    told: list[str] = []
    watch = FaultWatch(Harness(tmp_path).cfg, told.append)
    loop = FakeLoop([], [1])
    for fallbacks in (0, 1, 1):
        watch.poll({**loop.stats(), "compensation_fallbacks": fallbacks}, {}, loop)
    assert len(told) == 1 and told[0].startswith("servo compensation turned off"), told
