"""The model being identified: its parameters, the catalogue of effects, and the batch simulator.

**Parameters.** The fit works on Contract 1's parameter vector (22 entries). A model is that
vector plus the names that are free. The base model frees ``motor_inertia``, ``damping`` and ``coulomb``; each
effect of :data:`EFFECTS` frees its own parameters (the names of ``datasets.md``).

**Lumped mode ("sim units").** Without geometry only ratios are identifiable. Contract 1 states
the lumped model as I = 1 and G = gravity_per_inertia Γ. The fit uses an equivalent scaling
instead: every trial gets gravity torque 1 and the fit frees ``motor_inertia`` = 1/Γ, with the
torque parameters divided by Γ as well. The reason: the simulator takes G from the *trial*
(fixed for a whole batch), but it takes the inertia from the *parameter row*, which differs per
finite-difference row. So Γ becomes an ordinary parameter and one batch call still gives the
whole Jacobian. The per-inertia values are ``p_sim · Γ``; :func:`physical_params` converts.
A measured torque in lumped mode enters scaled by κ/Γ (κ = 1/I, the inverse inertia); that one
scale lives in the trials, so :class:`Simulator` rebuilds them when it changes.

**Torque gain.** ``torque_gain`` scales the measured torque. In geometry mode it is separable
from the inertia: the geometry fixes the load's inertia and gravity torque, so the ratio of
gravity to inertia is known and only the torque's scale is free. In lumped mode it *is* the
inverse inertia κ already fitted (a free scale of τ), so the effect exists in geometry mode only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from admittance.formats.dataset import TrialData
from admittance.formats.paramfile import PARAM_DEFAULTS, PARAM_NAMES

N_PARAMS = len(PARAM_NAMES)
INDEX = {name: i for i, name in enumerate(PARAM_NAMES)}
BASE_PARAMS = ("motor_inertia", "damping", "coulomb")
TAU_SCALE = "tau_scale"  # pseudo-parameter of lumped mode with a measured torque (see module doc)

# Parameters that are torques (or torque coefficients): in lumped mode they are divided by Γ.
TORQUE_PARAMS = frozenset(
    {
        "motor_inertia",
        "damping",
        "coulomb",
        "coulomb_asym",
        "stribeck_torque",
        "quadratic_drag",
        "cogging_amplitude",
        "torque_bias",
        "torque_drift",
        "spring_stiffness",
        "friction_ripple_amplitude",
    }
)

# Physical domain of each free parameter. Friction-like terms cannot be negative: a negative
# Coulomb level would push the joint, which no passive gearbox does.
LOWER = {
    "motor_inertia": 1e-9,
    "damping": 0.0,
    "coulomb": 0.0,
    "stribeck_torque": 0.0,
    "stribeck_velocity": 0.005,
    "load_coulomb": 0.0,
    "quadratic_drag": 0.0,
    "cogging_amplitude": 0.0,
    "time_delay": 0.0,
    "cogging_period": 1.5,
    "torque_gain": 0.05,  # the plant refuses a gain <= 0: a reversed or dead sensor is no plant
    "spring_stiffness": 0.0,  # a spring that pushes away from its neutral angle is no spring
    "friction_ripple_amplitude": 0.0,
    "friction_ripple_period": 1.5,
    TAU_SCALE: 1e-12,
}
UPPER = {
    "angle_offset": 0.5,
    "cogging_period": 64.0,
    "stribeck_velocity": 20.0,
    "time_delay": 0.5,
    "torque_gain": 20.0,
    "friction_ripple_period": 64.0,
}


@dataclass(frozen=True)
class Effect:
    """A candidate effect: the parameters it frees and the data it needs."""

    name: str
    params: tuple[str, ...]
    needs_torque: bool = False
    summary: str = ""
    # The parameters whose significance decides whether the effect is real (any one of them);
    # shape parameters (a Stribeck velocity, a cogging phase) are not evidence by themselves.
    # "Zero" is the parameter's Contract 1 default (0 for most, 1 for a gain).
    evidence: tuple[str, ...] = ()
    geometry_only: bool = False  # lumped mode already fits it (torque_gain: the inverse inertia)


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("stribeck", ("stribeck_torque", "stribeck_velocity"), False,
               "extra friction near zero speed", ("stribeck_torque",)),
        Effect("asymmetric_coulomb", ("coulomb_asym",), False,
               "Coulomb level differs with direction", ("coulomb_asym",)),
        Effect("load_dependent_coulomb", ("load_coulomb",), False,
               "Coulomb grows with the load torque", ("load_coulomb",)),
        Effect("angle_offset", ("angle_offset",), False,
               "measured zero differs from hanging down", ("angle_offset",)),
        Effect("quadratic_drag", ("quadratic_drag",), False,
               "drag growing with speed squared", ("quadratic_drag",)),
        Effect("cogging", ("cogging_amplitude", "cogging_phase", "cogging_period"), False,
               "torque ripple periodic in angle", ("cogging_amplitude",)),
        Effect("time_delay", ("time_delay",), True, "applied torque acts late", ("time_delay",)),
        Effect("torque_bias", ("torque_bias", "torque_drift"), True,
               "offset or drift of the measured torque", ("torque_bias", "torque_drift")),
        Effect("torque_gain", ("torque_gain",), True, "the measured torque is off by a factor",
               ("torque_gain",), geometry_only=True),
        Effect("spring", ("spring_stiffness", "spring_neutral"), False,
               "elastic torque towards a neutral angle (a cable, a hose)", ("spring_stiffness",)),
        Effect("friction_ripple", ("friction_ripple_amplitude", "friction_ripple_phase", "friction_ripple_period"),
               False, "Coulomb level periodic in the angle (gear-mesh friction)", ("friction_ripple_amplitude",)),
    )
}


def default_vector() -> np.ndarray:
    """Contract 1's defaults; motor_inertia, which has no default, is 1 until a fit sets it."""
    return np.array([1.0 if v is None else v for v in PARAM_DEFAULTS.values()], dtype=float)


def vector_from(params: dict[str, float]) -> np.ndarray:
    vec = default_vector()
    for name, value in params.items():
        vec[INDEX[name]] = value
    return vec


def bounds_for(names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    lower = np.array([LOWER.get(n, -np.inf) for n in names], dtype=float)
    upper = np.array([UPPER.get(n, np.inf) for n in names], dtype=float)
    return lower, upper


def free_params(mode: str, effects: Sequence[str], with_tau: bool,
                params_of: Mapping[str, Sequence[str]] | None = None) -> tuple[str, ...]:
    """The parameters a fit of the base model plus ``effects`` frees, in a fixed order.
    ``params_of`` narrows an effect to some of its parameters (a torque bias without drift)."""
    names = list(BASE_PARAMS)
    if mode == "lumped" and with_tau:
        names.append(TAU_SCALE)
    for effect in effects:
        names.extend((params_of or {}).get(effect, EFFECTS[effect].params))
    return tuple(names)


def physical_params(vec: np.ndarray, mode: str) -> dict[str, float]:
    """Contract 1 parameters from a sim-unit vector. Geometry mode: unchanged. Lumped mode: the
    per-inertia values with motor_inertia = 1 (Contract 1's lumped convention)."""
    out = {name: float(vec[i]) for i, name in enumerate(PARAM_NAMES)}
    if mode != "lumped":
        return out
    gamma = 1.0 / vec[INDEX["motor_inertia"]]
    for name in TORQUE_PARAMS:
        out[name] = float(vec[INDEX[name]] * gamma)
    out["motor_inertia"] = 1.0
    return out


def lumped_ratios(vec: np.ndarray, tau_scale: float | None) -> dict[str, float]:
    """The base model's identifiable ratios in lumped mode (datasets.md's ``base`` keys)."""
    gamma = 1.0 / vec[INDEX["motor_inertia"]]
    out = {
        "gravity_per_inertia": float(gamma),
        "damping_per_inertia": float(vec[INDEX["damping"]] * gamma),
        "coulomb_per_inertia": float(vec[INDEX["coulomb"]] * gamma),
    }
    if tau_scale is not None:
        out["inverse_inertia"] = float(tau_scale * gamma)
    return out


class Simulator:
    """The Rust batch simulator bound to a list of trials.

    The ``_rtcore.Trial`` objects are built once (they copy the arrays into Rust) and reused by
    every call; :meth:`subset` shares them, so a validation split costs nothing to set up.
    """

    def __init__(
        self,
        trials: Sequence[TrialData],
        mode: str,
        friction: str = "stick",
        max_step: float = 1e-3,
        tau_scale: float = 1.0,
        _built: list | None = None,
    ):
        self.trials = tuple(trials)
        self.mode = mode
        self.friction = friction
        self.max_step = max_step
        self.tau_scale = float(tau_scale)
        self._rt = _built if _built is not None else [self._build(tr) for tr in self.trials]

    def _build(self, trial: TrialData):
        from admittance import _rtcore

        tau = trial.tau
        if self.mode == "lumped":
            tau = None if tau is None else tau * self.tau_scale
            return _rtcore.Trial(trial.t, tau, load_inertia=0.0, gravity_torque=1.0)
        return _rtcore.Trial(trial.t, tau, load_inertia=trial.load_inertia, gravity_torque=trial.gravity_torque)

    def with_tau_scale(self, tau_scale: float) -> "Simulator":
        if tau_scale == self.tau_scale:
            return self
        return Simulator(self.trials, self.mode, self.friction, self.max_step, tau_scale)

    def subset(self, indices: Sequence[int]) -> "Simulator":
        picked = [self._rt[i] for i in indices]
        return Simulator(
            [self.trials[i] for i in indices],
            self.mode,
            self.friction,
            self.max_step,
            self.tau_scale,
            _built=picked,
        )

    @property
    def measured(self) -> list[np.ndarray]:
        return [tr.theta for tr in self.trials]

    def run(self, rows: np.ndarray, x0: np.ndarray, velocity: bool = False) -> list[np.ndarray]:
        """θ per trial, shape (S, n_t) (or (S, n_t, 2) with ω when ``velocity``), for parameter
        rows (S, N_PARAMS) and initial states (S, T, 2)."""
        from admittance import _rtcore

        rows = np.ascontiguousarray(rows, dtype=float)
        x0 = np.ascontiguousarray(x0, dtype=float)
        return _rtcore.simulate_batch(self._rt, rows, x0, max_step=self.max_step, friction=self.friction,
                                      return_velocity=velocity)

    def sensitivities(self, vector: np.ndarray, x0: np.ndarray, wrt: Sequence[str]) -> list[np.ndarray]:
        """Per trial, (len(wrt) + 3, n_t): θ under ``vector`` from ``x0`` (T, 2), then ∂θ/∂p for each
        name of ``wrt``, then ∂θ/∂θ0 and ∂θ/∂ω0: one pass of the Rust plant's forward sensitivities."""
        from admittance import _rtcore

        vector = np.ascontiguousarray(vector, dtype=float)
        x0 = np.ascontiguousarray(x0, dtype=float).reshape(1, -1, 2)
        return _rtcore.simulate_sensitivities(self._rt, vector, x0, list(wrt), max_step=self.max_step,
                                              friction=self.friction)
