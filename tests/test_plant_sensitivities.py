"""The binding of the plant's forward sensitivities (``_rtcore.simulate_sensitivities``): shapes,
the angle row equal to ``simulate_batch``'s, and hostile inputs refused with a ValueError."""

from __future__ import annotations

import numpy as np
import pytest

from admittance import _rtcore


def _trials():
    t = np.arange(0.0, 1.0, 1 / 120)
    return [_rtcore.Trial(t, None, load_inertia=2e-3, gravity_torque=0.4),
            _rtcore.Trial(t[:50], 0.1 * np.sin(3 * t[:50]), load_inertia=1e-3, gravity_torque=0.3)]


def _params():
    p = np.array(_rtcore.PARAM_DEFAULTS, dtype=float)
    p[_rtcore.PARAM_NAMES.index("motor_inertia")] = 0.0147
    p[_rtcore.PARAM_NAMES.index("coulomb")] = 0.01
    p[_rtcore.PARAM_NAMES.index("damping")] = 0.02
    return p


def test_rows_are_the_angle_then_each_parameter_then_the_initial_state():
    trials, p = _trials(), _params()
    x0 = np.array([[[1.0, 0.0], [0.5, -0.2]]])
    out = _rtcore.simulate_sensitivities(trials, p, x0, ["damping", "coulomb"], max_step=1e-3)
    plain = _rtcore.simulate_batch(trials, p[None, :], x0, max_step=1e-3)
    for block, sim, trial in zip(out, plain, trials):
        assert block.shape == (5, trial.n_samples)
        np.testing.assert_array_equal(block[0], sim[0])
        assert block[3, 0] == 1.0 and block[4, 0] == 0.0  # ∂θ/∂θ0 starts at 1, ∂θ/∂ω0 at 0


@pytest.mark.parametrize("wrt, x0, message", [
    (["nonsense"], np.zeros((1, 2, 2)), "not a parameter name"),
    (["damping", "damping"], np.zeros((1, 2, 2)), "twice"),
    (["damping"], np.zeros((1, 3, 2)), "x0"),
    (["damping"], np.full((1, 2, 2), np.nan), "finite"),
])
def test_bad_requests_are_refused(wrt, x0, message):
    with pytest.raises(ValueError, match=message):
        _rtcore.simulate_sensitivities(_trials(), _params(), x0, wrt)
