"""admittance.sim: the parameter facade, the batch binding, and Rust == the Python reference."""

from __future__ import annotations

import numpy as np
import pytest

from admittance import _rtcore, sim
from admittance.errors import ConfigError, DataError
from oracles import reference

BASE = {"motor_inertia": 2e-3, "damping": 0.01, "coulomb": 0.01}

# One entry per effect of Contract 1, each strong enough to change the trajectory visibly.
EFFECTS = {
    "base": {},
    "coulomb_asym": {"coulomb_asym": 0.004},
    "stribeck": {"stribeck_torque": 0.006, "stribeck_velocity": 0.2},
    "load_coulomb": {"load_coulomb": 0.1},
    "angle_offset": {"angle_offset": 0.05},
    "quadratic_drag": {"quadratic_drag": 2e-3},
    "cogging": {"cogging_amplitude": 0.004, "cogging_period": 8.0, "cogging_phase": 0.4},
    "time_delay": {"time_delay": 0.017},
    "torque_bias": {"torque_bias": 0.006},
    "torque_drift": {"torque_drift": 0.01},
    "tanh_k": {"tanh_k": 40.0},
    "torque_gain": {"torque_gain": 0.8},
    "torque_gain_and_bias": {"torque_gain": 1.25, "torque_bias": 0.006},
    "spring": {"spring_stiffness": 0.05, "spring_neutral": 0.2},
    "friction_ripple": {"friction_ripple_amplitude": 0.004, "friction_ripple_period": 6.0,
                        "friction_ripple_phase": 0.3},
}


@pytest.fixture(scope="module")
def driven_trial():
    """Non-uniform samples over 1.5 s with a person-like torque and a gravity load."""
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.004, 0.012, 180))
    t -= t[0]
    tau = 0.06 * np.sin(2.0 * t) + 0.02 * np.sin(9.0 * t)
    return sim.make_trial(t, tau, load_inertia=1e-3, gravity_torque=0.08)


@pytest.fixture(scope="module")
def free_swing():
    return sim.make_trial(np.arange(0.0, 1.0, 1 / 120), None, load_inertia=1e-3, gravity_torque=0.15)


def test_torque_gain_is_entry_16_and_defaults_to_one():
    """Contract 1's order: torque_gain was added after tanh_k, so older indices are unchanged."""
    assert sim.PARAM_NAMES.index("torque_gain") == 16 == sim.PARAM_NAMES.index("tanh_k") + 1
    assert sim.PARAM_DEFAULTS["torque_gain"] == 1.0


def test_new_effects_are_appended_after_torque_gain_and_default_off():
    """spring and friction_ripple were appended at the end: every older index is unchanged."""
    new = ("spring_stiffness", "spring_neutral", "friction_ripple_amplitude", "friction_ripple_period",
           "friction_ripple_phase")
    assert sim.PARAM_NAMES[17:] == new
    assert all(sim.PARAM_DEFAULTS[n] == 0.0 for n in new)


def test_pack_fills_defaults_and_unpack_inverts():
    vector = sim.pack_params({"motor_inertia": 0.5, "coulomb": 0.1})
    assert vector.shape == (len(sim.PARAM_NAMES),)
    values = sim.unpack_params(vector)
    assert values["motor_inertia"] == 0.5 and values["coulomb"] == 0.1
    assert values["stribeck_velocity"] == 0.1 and values["tanh_k"] == 100.0
    assert sim.pack_params(values).tolist() == vector.tolist()


@pytest.mark.parametrize(
    ("mapping", "words"),
    [
        ({"motor_inertia": 1.0, "dampening": 0.1}, "unknown plant parameter(s) dampening"),
        ({"damping": 0.1}, "missing required plant parameter(s): motor_inertia"),
        ({"motor_inertia": "heavy"}, "must be a number"),
        ({"motor_inertia": float("nan")}, "must be finite"),
    ],
)
def test_pack_refuses_bad_mappings(mapping, words):
    with pytest.raises(ConfigError, match=words.replace("(", r"\(").replace(")", r"\)")):
        sim.pack_params(mapping)


def test_unpack_refuses_wrong_length():
    with pytest.raises(ConfigError, match="shape"):
        sim.unpack_params(np.zeros(3))


def test_trial_keeps_copies_of_its_arrays():
    t = np.linspace(0.0, 1.0, 11)
    tau = np.ones(11)
    trial = sim.make_trial(t, tau, load_inertia=0.1, gravity_torque=0.2)
    t[:] = 0.0
    tau[:] = 5.0
    assert trial.t[-1] == 1.0 and trial.tau[0] == 1.0
    assert (trial.n_samples, trial.duration, trial.has_tau) == (11, 1.0, True)
    assert trial.substeps(0.05) == 20


@pytest.mark.parametrize(
    ("t", "tau", "words"),
    [
        ([0.0, 0.1, 0.1], None, "strictly increasing"),
        ([0.0, float("nan")], None, "finite"),
        ([0.0, 0.1], [0.0, 1.0, 2.0], "tau has 3 samples but t has 2"),
        ([[0.0, 0.1]], None, "dimension"),
        ([], None, "at least one"),
    ],
)
def test_bad_trials_raise_value_error_and_data_error(t, tau, words):
    with pytest.raises(ValueError, match=words):
        _rtcore.Trial(t, tau)
    with pytest.raises(DataError, match=words):
        sim.make_trial(t, tau)


def test_batch_shapes_and_rows(driven_trial, free_swing):
    sets = np.stack([sim.pack_params(BASE), sim.pack_params({**BASE, "damping": 0.03})])
    x0 = np.zeros((2, 2, 2))
    x0[:, :, 0] = 0.3
    theta = sim.simulate_many([driven_trial, free_swing], sets, x0)
    both = sim.simulate_many([driven_trial, free_swing], sets, x0, return_velocity=True, threads=1)
    assert [a.shape for a in theta] == [(2, driven_trial.n_samples), (2, free_swing.n_samples)]
    assert both[1].shape == (2, free_swing.n_samples, 2)
    np.testing.assert_array_equal(both[0][..., 0], theta[0])
    single = sim.simulate(free_swing, {**BASE, "damping": 0.03}, 0.3, 0.0)
    np.testing.assert_array_equal(single, theta[1][1])


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"friction": "viscous"}, "unknown friction law"),
        ({"max_step": 0.0}, "max_step"),
        ({"threads": 0}, "threads"),
        ({"x0": np.zeros((1, 2, 2))}, r"x0 must have shape"),
        ({"params": np.zeros((1, 5))}, f"{len(sim.PARAM_NAMES)} columns"),
        ({"params": np.zeros((1, len(sim.PARAM_NAMES)))}, "motor_inertia must be > 0"),
        ({"params": sim.pack_params({**BASE, "torque_gain": 0.0})[None, :]}, "torque_gain must be > 0"),
    ],
)
def test_batch_refuses_bad_requests(free_swing, kwargs, words):
    request = {"params": sim.pack_params(BASE)[None, :], "x0": np.zeros((1, 1, 2))} | kwargs
    params, x0 = request.pop("params"), request.pop("x0")
    with pytest.raises(ValueError, match=words):
        _rtcore.simulate_batch([free_swing], params, x0, **request)
    with pytest.raises(ConfigError, match=words):
        sim.simulate_many([free_swing], params, x0, **request)


@pytest.mark.parametrize("friction", sim.FRICTION_LAWS)
@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_rust_matches_the_python_reference(driven_trial, effect, friction):
    params = {**BASE, **EFFECTS[effect]}
    fast = sim.simulate(driven_trial, params, 0.4, -0.5, max_step=1e-3, friction=friction, return_velocity=True)
    slow = reference.simulate_reference(driven_trial, params, 0.4, -0.5, max_step=1e-3, friction=friction,
                                  return_velocity=True)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-9)
    plain = sim.simulate(driven_trial, BASE, 0.4, -0.5, max_step=1e-3, friction=friction)
    if effect != "base" and not (effect == "tanh_k" and friction == "stick"):
        assert np.abs(fast[:, 0] - plain).max() > 1e-4, f"{effect} did not change the trajectory"


def test_reference_matches_on_a_free_swing_with_measurement_effects(free_swing):
    # Gain, bias and drift correct a measured torque; a free swing has none, so both sides ignore them.
    params = {**BASE, "torque_bias": 0.01, "torque_drift": 0.01, "torque_gain": 0.7}
    fast = sim.simulate(free_swing, params, 1.0, 0.0)
    np.testing.assert_allclose(fast, reference.simulate_reference(free_swing, params, 1.0, 0.0), atol=1e-9)
    np.testing.assert_array_equal(fast, sim.simulate(free_swing, BASE, 1.0, 0.0))


def test_stick_holds_exactly_through_the_binding():
    trial = sim.make_trial(np.linspace(0, 2, 201), np.full(201, 0.009))
    theta = sim.simulate(trial, BASE, 0.25, 0.0, return_velocity=True)
    assert np.all(theta[:, 0] == 0.25) and np.all(theta[:, 1] == 0.0)


def test_admittance_gate_from_python():
    assert _rtcore.admittance_check_stable(0.01, 0.05, 0.02, 1e-3) is None
    assert "h·B/I" in _rtcore.admittance_check_stable(0.001, 2.0, 0.0, 1e-3)


def test_degenerate_batches():
    single = sim.make_trial([0.5])
    assert sim.simulate(single, BASE, 0.2, 0.1).tolist() == [0.2]
    assert sim.simulate_many([], sim.pack_params(BASE)[None, :], np.zeros((1, 0, 2))) == []


@pytest.mark.parametrize("effect", ["base", "stribeck", "load_coulomb", "cogging", "spring", "friction_ripple",
                                    "torque_gain_and_bias", "time_delay"])
def test_rust_plant_converges_to_the_test_oracle(effect):
    """A third reading of Contract 1 with another integrator (tests/oracles/ivp.py: solve_ivp
    between stick events): the Rust plant approaches it at first order as the step shrinks."""
    from oracles import ivp as ivp_oracle

    params = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084,
              **{k: v * (10.0 if k in ("coulomb_asym", "stribeck_torque", "cogging_amplitude", "torque_bias",
                                       "friction_ripple_amplitude") else 1.0) for k, v in EFFECTS[effect].items()}}
    t = np.arange(361) / 120
    tau = 0.25 * np.sin(2.1 * t) * np.clip(t / 0.5, 0, 1) if "torque" in effect or effect == "time_delay" else None
    x0 = (0.0, 0.0) if tau is not None else (1.4, 0.0)
    truth = ivp_oracle.simulate(params, 0.004, 0.3, t, x0, tau)
    trial = sim.make_trial(t, tau, load_inertia=0.004, gravity_torque=0.3)
    errors = [np.sqrt(np.mean((sim.simulate(trial, params, *x0, max_step=h) - truth) ** 2)) for h in (1e-3, 1e-4)]
    assert errors[0] < 1e-3  # 1 ms, the fit's step: well under the data's noise
    assert errors[1] < 0.25 * errors[0]  # first order: 10× finer, ~10× closer
