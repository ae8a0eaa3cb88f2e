"""Property tests of admittance.sim: the name <-> vector codec, and Rust == reference on random plants."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance import sim
from oracles import reference

from helpers import examples

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@given(st.dictionaries(st.sampled_from(sim.PARAM_NAMES[1:]), finite))
def test_pack_unpack_round_trip(extra):
    mapping = {"motor_inertia": 1.0, **extra}
    values = sim.unpack_params(sim.pack_params(mapping))
    assert {name: values[name] for name in mapping} == mapping
    assert all(values[n] == sim.PARAM_DEFAULTS[n] for n in sim.PARAM_NAMES if n not in mapping)


plants = st.fixed_dictionaries({
    "motor_inertia": st.floats(1e-4, 1e-2),
    "damping": st.floats(0.0, 0.1),
    "coulomb": st.floats(0.0, 0.05),
    "coulomb_asym": st.floats(-0.02, 0.02),
    "stribeck_torque": st.floats(0.0, 0.02),
    "stribeck_velocity": st.floats(0.01, 1.0),
    "load_coulomb": st.floats(0.0, 0.5),
    "angle_offset": st.floats(-0.2, 0.2),
    "quadratic_drag": st.floats(0.0, 0.01),
    "cogging_amplitude": st.floats(0.0, 0.01),
    "cogging_period": st.floats(0.0, 20.0),
    "time_delay": st.floats(0.0, 0.05),
    "torque_bias": st.floats(-0.02, 0.02),
    "torque_drift": st.floats(-0.02, 0.02),
    "torque_gain": st.floats(0.5, 2.0),
})


@settings(max_examples=examples(25))
@given(plants, st.sampled_from(sim.FRICTION_LAWS), st.floats(-1.5, 1.5), st.floats(-3.0, 3.0))
def test_rust_matches_reference_on_random_plants(params, friction, theta0, omega0):
    t = np.linspace(0.0, 0.4, 41)
    trial = sim.make_trial(t, 0.05 * np.sin(7.0 * t), load_inertia=5e-4, gravity_torque=0.05)
    fast = sim.simulate(trial, params, theta0, omega0, max_step=2e-3, friction=friction, return_velocity=True)
    slow = reference.simulate_reference(trial, params, theta0, omega0, max_step=2e-3, friction=friction,
                                  return_velocity=True)
    assert np.all(np.isfinite(fast))
    np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-9)
