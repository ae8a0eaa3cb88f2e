"""Every admission gate of the effect search, and the data checks, each in a test that fails when
the gate is removed (tried by mutation: see docs/identification.md, "Gates and their tests").

The gates are tested where they live, on inputs built to sit just on the refused side, so that a
removed gate changes the verdict; none of these runs a whole identification.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from admittance.ident.crossval import paired_gain
from admittance.formats.trial import TrialData
from admittance.ident.effects import Evidence, physical_problems, required_sigma
from admittance.ident.fit import FitResult
from admittance.ident.model import vector_from

def _fit(free=(), sigma=None, residuals=None, **values) -> FitResult:
    vector = vector_from({"motor_inertia": 0.01, "damping": 0.02, "coulomb": 0.05, **values})
    return FitResult(vector, 1.0, tuple(free), dict(sigma or {}), np.zeros((0, 2)), list(residuals or []), 0, 0, 0.0)


# --- crossval.py: the pooled-gain floor -------------------------------------------------------

def test_a_consistent_gain_below_the_floor_is_not_supported():
    """Every unit improves by 2 %: significant, a majority, but below the 3 % floor."""
    rng = np.random.default_rng(0)
    current = [rng.normal(0.0, 1.0, 500) for _ in range(12)]
    candidate = [0.98 * r for r in current]
    gain = paired_gain(current, candidate, list(range(12)))
    assert gain.gain_lower_bound > 0 and gain.majority
    assert not gain.supported(0.03)
    assert gain.supported(0.01)


# --- search.py: the fold-stability test -------------------------------------------------------

def test_an_effect_that_changes_sign_or_swings_across_folds_is_not_one_effect():
    from admittance.ident.search import fold_instability

    ev = Evidence("quadratic_drag", params=("quadratic_drag",))
    stable = [_fit(quadratic_drag=v) for v in (0.010, 0.011, 0.009)]
    flips = [_fit(quadratic_drag=v) for v in (0.010, -0.002, 0.009)]
    swings = [_fit(quadratic_drag=v) for v in (0.001, 0.030, 0.001)]
    assert fold_instability(ev, stable) == ""
    assert "changes sign" in fold_instability(ev, flips)
    assert "more than its own size" in fold_instability(ev, swings)


def _assessed(monkeypatch, fold_values, pooled_gain=0.10):
    """search.assess on a quadratic-drag candidate (10 σ, 10 % training gain) whose
    cross-validation is given: its folds' drag values and its pooled gain (a lower bound above
    zero, every fold improving). The regime test passes. Returns (admitted model or None, evidence)."""
    from admittance.ident import search
    from admittance.ident.crossval import PairedGain

    residual = [np.full(100, 1e-3)]
    refit = _fit(free=("quadratic_drag",), sigma={"quadratic_drag": 0.001}, residuals=[0.9 * r for r in residual],
                 quadratic_drag=0.01)
    folds = [_fit(free=("quadratic_drag",), quadratic_drag=v) for v in fold_values]
    gain = PairedGain(pooled_gain, pooled_gain / 2, 5.0, 1.0, len(folds), len(folds), len(folds), 1e-3, 1e-3)
    monkeypatch.setattr(search, "cross_validate", lambda ctx, full: search.Scored(full, folds, residual))
    monkeypatch.setattr(search, "compare", lambda ctx, current, scored: gain)
    monkeypatch.setattr(search, "regime_inconsistency", lambda *args: ("", []))
    ctx = SimpleNamespace(settings=search.SearchSettings(), torque_scale=1.0, sim=SimpleNamespace(mode="geometry"))
    ev = Evidence("quadratic_drag", params=("quadratic_drag",))
    return search.assess(ctx, SimpleNamespace(full=_fit(residuals=residual)), ev, refit), ev


def test_assess_admits_a_stable_supported_effect(monkeypatch):
    admitted, ev = _assessed(monkeypatch, (0.010, 0.011, 0.009))
    assert admitted is not None and ev.accepted and not ev.stand_in


def test_assess_refuses_an_effect_whose_folds_disagree(monkeypatch):
    """The fold-stability gate where the search applies it (a removed call admits it)."""
    admitted, ev = _assessed(monkeypatch, (0.010, -0.002, 0.009))
    assert admitted is None and not ev.accepted
    assert ev.reason.startswith("not the same effect in every fold")


def test_assess_refuses_a_cross_validated_gain_below_the_floor(monkeypatch):
    """The 3 % pooled-gain floor where the search applies it: a significant 2 % gain is refused."""
    admitted, ev = _assessed(monkeypatch, (0.010, 0.011, 0.009), pooled_gain=0.02)
    assert admitted is None and not ev.accepted
    assert "≤ 3 %" in ev.reason


def test_a_fit_the_regime_halves_show_stuck_is_judged_again_from_their_optimum(monkeypatch):
    """The regime test flags a fit; refitted from a half's optimum it fits materially better and
    is one model: judged again, it is named (not a stand-in), and the reason says why. A flagged
    fit the halves cannot improve stays flagged (a stand-in, refused here for its folds' 2 of 3)."""
    from admittance.ident import search
    from admittance.ident.crossval import PairedGain

    calls = []

    def regimes(ctx, evidence, fit, current, halves_out=None):
        calls.append(fit)
        if fit.value("quadratic_drag") == 0.01:  # the stuck fit
            halves_out[:] = [fit, fit]
            return "the model with it is not one model", []
        return "", []

    _assessed(monkeypatch, (0.010, 0.011, 0.009))
    monkeypatch.setattr(search, "regime_inconsistency", regimes)
    better = _fit(free=("quadratic_drag",), sigma={"quadratic_drag": 0.001}, residuals=[np.full(100, 0.5e-3)],
                  quadratic_drag=0.012)
    monkeypatch.setattr(search, "restart_from_halves", lambda ctx, fit, halves: better if halves else None)
    ctx = SimpleNamespace(settings=search.SearchSettings(), torque_scale=1.0, sim=SimpleNamespace(mode="geometry"),
                          say=lambda message: None)
    current = SimpleNamespace(full=_fit(residuals=[np.full(100, 1e-3)]))
    refit = _fit(free=("quadratic_drag",), sigma={"quadratic_drag": 0.001}, residuals=[np.full(100, 0.9e-3)],
                 quadratic_drag=0.01)
    ev = Evidence("quadratic_drag", params=("quadratic_drag",))
    assert search.assess(ctx, current, ev, refit) is not None
    assert ev.accepted and not ev.stand_in and ev.reason.startswith("refitted from a regime half's optimum")
    assert ev.values["quadratic_drag"][0] == 0.012 and len(calls) == 2
    # A restart that keeps finding a better fit the test still flags: tried MAX_RESTARTS times, not for ever.
    calls.clear()
    monkeypatch.setattr(search, "regime_inconsistency",
                        lambda ctx, evidence, fit, current, halves_out=None: (calls.append(fit), halves_out.extend([fit]),
                                                                               ("the model with it is not one model", []))[-1])
    monkeypatch.setattr(search, "transfer_loss", lambda *args: "")
    looping = Evidence("quadratic_drag", params=("quadratic_drag",))
    assert search.assess(ctx, current, looping, refit) is not None and looping.stand_in
    assert len(calls) == search.MAX_RESTARTS + 1
    monkeypatch.setattr(search, "regime_inconsistency", regimes)
    # No better start: the flag stands.
    monkeypatch.setattr(search, "restart_from_halves", lambda ctx, fit, halves: None)
    monkeypatch.setattr(search, "compare", lambda ctx, c, s: PairedGain(0.1, 0.05, 5.0, 1.0, 2, 3, 3, 1e-3, 1e-3))
    ev = Evidence("quadratic_drag", params=("quadratic_drag",))
    assert search.assess(ctx, current, ev, refit) is None and ev.stand_in


# --- effects.py / search.py: the look-elsewhere correction ------------------------------------

def test_the_look_elsewhere_correction_raises_the_bar_for_grid_searched_shapes():
    assert required_sigma(3.0, 1) == pytest.approx(3.0, abs=1e-9)
    assert required_sigma(3.0, 4) == pytest.approx(3.40, abs=0.01)
    assert required_sigma(3.0, 31) == pytest.approx(3.94, abs=0.02)


def test_a_cogging_term_at_3_5_sigma_is_refused_for_its_31_looks():
    """assess(): 3.5 σ passes a single look but not the 31 cogging periods."""
    from admittance.ident.search import SearchSettings, assess

    ctx = SimpleNamespace(settings=SearchSettings(), torque_scale=1.0, sim=SimpleNamespace(mode="geometry"))
    residual = [np.full(100, 1e-3)]
    current = SimpleNamespace(full=_fit(residuals=residual))
    refit = _fit(free=("cogging_amplitude", "cogging_phase"), sigma={"cogging_amplitude": 0.002},
                 residuals=[0.999 * r for r in residual], cogging_amplitude=0.007, cogging_period=8.0,
                 cogging_phase=0.3)
    ev = Evidence("cogging", params=("cogging_amplitude", "cogging_phase"))
    assert assess(ctx, current, ev, refit) is None
    assert ev.significance == pytest.approx(3.5)
    assert "needs 3.9 σ" in ev.reason


# --- effects.py: physical sense, and a base model on a bound ----------------------------------

def test_an_inertia_already_on_its_bound_is_the_rig_not_the_effect():
    """A passive pendulum has no motor inertia: the base fit sits on the bound, and an effect
    that leaves it there is judged on what it does itself; one that puts it there is refused."""
    ev = Evidence("quadratic_drag", params=("quadratic_drag",))
    passive = _fit(motor_inertia=1e-9)
    with_drag = _fit(motor_inertia=1e-9, quadratic_drag=0.01)
    assert physical_problems(ev, with_drag, passive) == []
    # Drag cannot take over the period: a motor inertia of 0 with it is a rig without a motor.
    assert physical_problems(ev, with_drag, _fit()) == []
    # A delay can: putting the inertia on its bound, it replaced it ...
    delay = Evidence("time_delay", params=("time_delay",))
    with_delay = _fit(motor_inertia=1e-9, time_delay=0.01)
    assert "collapsed" in physical_problems(delay, with_delay, _fit())[-1]
    assert "collapsed" in physical_problems(delay, with_delay)[-1]
    # ... unless the model without it was there already; in lumped mode 0 is no pendulum.
    assert physical_problems(delay, with_delay, passive) == []
    assert "collapsed" in physical_problems(ev, with_drag, _fit(), mode="lumped")[-1]


# --- fit.py: several starts for the initial states --------------------------------------------

def _swing(n=600, rate=100.0, theta0=1.0):
    from admittance.ident.model import Simulator

    t = np.arange(n) / rate
    trial = TrialData("a.csv", t, np.zeros(n), None, load_inertia=0.02, gravity_torque=0.5)
    vector = vector_from({"motor_inertia": 0.002, "damping": 0.002, "coulomb": 0.002})
    sim = Simulator([trial], "geometry")
    truth = sim.run(vector[None, :], np.array([[[theta0, 0.0]]]))[0][0]
    return Simulator([TrialData("a.csv", t, truth, None, 0.02, 0.5)], "geometry"), vector


def test_initial_states_keep_each_trials_best_start():
    """A start that swings over the top settles in the wrong basin; the second start is kept."""
    from admittance.ident.fit import fit_initial_states_multi

    sim, vector = _swing()
    wrong, right = np.array([[2.5, 0.0]]), np.array([[0.97, 0.05]])  # 2.5 rad: over the top, another basin
    alone = fit_initial_states_multi(sim, vector, [wrong])
    both = fit_initial_states_multi(sim, vector, [wrong, right])
    assert alone.rmse > 0.1
    assert both.rmse < 1e-3
    assert both.x0[0, 0] == pytest.approx(1.0, abs=1e-3)


# --- sensor.py: the whiteness threshold -------------------------------------------------------

def test_a_faintly_coloured_residual_is_not_white():
    from admittance.ident.angle_sensor import Sensor, noise_verdict

    rng = np.random.default_rng(3)
    white = [rng.normal(0.0, 1e-3, 2000) for _ in range(4)]
    coloured = []
    for e in white:
        x = e.copy()
        for k in range(1, x.size):
            x[k] += 0.05 * x[k - 1]  # Ljung–Box p ≈ 0.003 with this seed
        coloured.append(x)
    measured = [np.zeros(2000)] * 4
    assert noise_verdict(measured, white, Sensor()).white
    verdict = noise_verdict(measured, coloured, Sensor())
    assert 1e-4 < verdict.ljung_box_p < 0.01  # just on the refused side of 0.01
    assert not verdict.white


def _ar1(rng, n, rho, sigma):
    shocks = rng.normal(0.0, sigma, n)
    x = np.empty(n)
    x[0] = shocks[0]
    for k in range(1, n):
        x[k] = rho * x[k - 1] + shocks[k]
    return x


def test_a_faint_colour_beyond_the_sensors_own_is_not_white():
    """The coloured-noise branch: the rest periods show AR(1) noise (ρ 0.6, motion capture's
    filter); where the joint moves a faint extra colour remains once that AR(1) is removed."""
    from admittance.ident.angle_sensor import Sensor, noise_verdict

    def verdict(extra):
        rng = np.random.default_rng(5)
        residuals, at_rest = [], []
        for _ in range(3):
            x = _ar1(rng, 4000, 0.6, 1e-3)
            x[2000:] += extra * np.roll(x[2000:], 3)
            residuals.append(x)
            at_rest.append(np.arange(4000) < 2000)
        return noise_verdict([np.zeros(4000)] * 3, residuals, Sensor(), at_rest)

    assert verdict(0.0).white and verdict(0.0).correlation == pytest.approx(0.6, abs=0.03)
    coloured = verdict(0.05)
    assert coloured.correlation == pytest.approx(0.6, abs=0.03)  # the AR(1) branch was taken
    assert 1e-4 < coloured.ljung_box_p < 0.01  # just on the refused side of 0.01
    assert not coloured.white


def test_a_faint_colour_under_an_encoders_rounding_is_not_white():
    """The encoder branch (the bootstrap over the rounding): noise before a 4096-tick encoder,
    white or with a faint lag-3 colour."""
    from admittance.ident.angle_sensor import Sensor, noise_verdict

    sensor = Sensor(2 * math.pi / 4096, 0.0, "manifest")

    def verdict(colour):
        rng = np.random.default_rng(7)
        measured, residuals = [], []
        for k in range(4):
            truth = 0.8 * np.sin(1.3 * np.arange(3000) / 100 + k)
            noise = rng.normal(0.0, 1e-3, truth.size)
            noise[3:] += colour * noise[:-3]
            reading = sensor.read(truth + noise)
            measured.append(reading)
            residuals.append(truth - reading)
        return noise_verdict(measured, residuals, sensor)

    assert verdict(0.0).white and verdict(0.0).quantised
    coloured = verdict(0.05)
    assert 1e-4 < coloured.ljung_box_p < 0.01
    assert not coloured.white


# --- datacheck.py: every check, and a clean swing passes all ----------------------------------

def _free_swing(n=1200, rate=100.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    omega = math.sqrt(0.5 / 0.022)  # load alone 0.02, motor 0.002
    theta = 0.8 * np.exp(-0.15 * t) * np.cos(omega * t) + rng.normal(0.0, 1e-3, n)
    return t, theta


def _trial(t, theta, name="a.csv"):
    return TrialData(name, np.asarray(t, float), np.asarray(theta, float), None, 0.02, 0.5)


def test_a_clean_swing_passes_every_check():
    from admittance.ident.datacheck import check_trial

    assert check_trial(_trial(*_free_swing()), "geometry") == []


def test_two_drops_in_one_file_are_found_where_the_swing_grows_again():
    from admittance.ident.datacheck import check_trial

    t, theta = _free_swing(n=2400)
    theta[1200:] = _free_swing(n=1200, seed=1)[1]  # let go again from 0.8 rad
    theta[1200:] += theta[1199] - theta[1200]  # no step at the splice: only the energy says it
    (found,) = check_trial(_trial(t, theta), "geometry")
    assert found.kind == "re-release" and found.action == "drop"
    assert 1200 <= found.sample < 1300


def test_a_step_in_the_angle_is_a_jump_but_a_single_outlier_is_not():
    from admittance.ident.datacheck import check_trial

    t, theta = _free_swing()
    spiked = theta.copy()
    spiked[500] += 0.3
    assert check_trial(_trial(t, spiked), "lumped") == []
    stepped = theta.copy()
    stepped[500:] += 0.3
    kinds = {f.kind: f.sample for f in check_trial(_trial(t, stepped), "lumped")}
    assert kinds.get("jump") == 500


def test_a_frozen_reading_is_stuck():
    from admittance.ident.datacheck import check_trial

    t, theta = _free_swing()
    # Find a fast stretch, and freeze it.
    k = int(np.argmax(np.abs(np.diff(theta[:300]))))
    frozen = theta.copy()
    frozen[k : k + 8] = frozen[k]
    found = [f for f in check_trial(_trial(t, frozen), "lumped") if f.kind == "stuck"]
    assert found and found[0].sample == k


def test_a_clipped_angle_is_found():
    from admittance.ident.datacheck import check_trial

    t, theta = _free_swing()
    clipped = np.minimum(theta, 0.6)
    found = [f for f in check_trial(_trial(t, clipped), "lumped") if f.kind == "clipping"]
    assert found and clipped[found[0].sample] == 0.6


def test_a_slow_clock_is_refused_where_the_load_cannot_swing_that_fast():
    from admittance.ident.datacheck import check_trial

    t, theta = _free_swing()
    assert check_trial(_trial(t * 1.0, theta), "geometry") == []
    # Time stamps 10 % short: the swing looks faster than the 0.02 kg·m² load alone allows.
    (found,) = check_trial(_trial(t * 0.9, theta), "geometry")
    assert found.kind == "clock" and found.action == "refuse"


def test_screen_drops_a_spliced_trial_and_refuses_when_nothing_is_left(tmp_path):
    from admittance.errors import DataError
    from admittance.ident.datacheck import screen
    from admittance.formats.trial import Dataset

    t, theta = _free_swing()
    stepped = theta.copy()
    stepped[500:] += 0.3
    good, bad = _trial(t, theta, "good.csv"), _trial(t, stepped, "bad.csv")
    lines = []
    kept, findings = screen(Dataset("geometry", (good, bad), folder=tmp_path), lines.append)
    assert [tr.name for tr in kept.trials] == ["good.csv"]
    assert len(lines) == 1 and lines[0].startswith("bad.csv: sample 500: jump")
    with pytest.raises(DataError, match="bad.csv"):
        screen(Dataset("geometry", (bad,), folder=tmp_path))


# --- a passive rig: the base model on a bound is no reason to refuse an effect ----------------

def test_a_passive_rod_pendulum_with_drag_gets_its_drag_named(tmp_path):
    """No motor: motor inertia 0, which the base fit puts on its bound. Quadratic drag is tried
    (not refused for a bound the base model was already on) and named."""
    from admittance.formats.dataset import load_dataset
    from admittance.ident.effects import candidate_effects
    from admittance.ident.identify import identify_dataset
    from admittance.ident.synthetic import SynthSpec, generate

    spec = SynthSpec(n_trials=6, duration=5.0, seed=2, params={"motor_inertia": 1e-9, "damping": 0.004, "coulomb": 0.004},
                     effects={"quadratic_drag": 0.01})
    j = identify_dataset(load_dataset(generate(tmp_path, spec))).to_json()
    judged = [e for round_ in j["evidence"] for e in round_]
    # Every candidate is tried in the first round, and none is refused for the bound.
    assert {e["effect"] for e in j["evidence"][0]} == set(candidate_effects([], False, "geometry"))
    assert not any("collapsed" in e["reason"] for e in judged)
    assert j["effects"] == ["quadratic_drag"]
    assert j["rmse_after"] < 0.8 * j["rmse_before"]


# --- the summary line ---------------------------------------------------------------------------

def test_the_summary_line_lists_stand_ins_groups_and_dropped_trials():
    from admittance.ident.cli import summary_line
    from admittance.ident.datacheck import Finding
    from admittance.ident.search import SearchOutcome

    search = SearchOutcome(["angle_offset", "torque_bias"], _fit(), [], [], None,
                           equivalents={"torque_bias": ["asymmetric_coulomb"]}, stand_ins=["angle_offset"])
    result = SimpleNamespace(mode="geometry", effects=search.claimed, stand_ins=search.stand_ins, search=search,
                             data_checks=[Finding("t07.csv", 812, "jump", "...", "drop")],
                             before=SimpleNamespace(rmse=0.012), after=SimpleNamespace(rmse=0.002),
                             timings={"total": 3.0})
    line = summary_line(result)
    assert "effects: none" in line
    assert "stand-ins: angle_offset" in line
    assert "torque_bias or asymmetric_coulomb" in line and "undriven drops" in line
    assert "dropped: t07.csv" in line
