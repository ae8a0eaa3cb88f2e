//! The plant's parameter vector: names, order, defaults and validation (Contract 1).
//!
//! The identification code works on a flat `f64` vector (finite differences, optimisers), the
//! simulator on named fields. `PARAM_NAMES` fixes the order once; `Params::from_slice` and
//! `Params::to_array` are the only two places that know it, so the two views cannot drift.
use crate::error::{require_finite, PlantError};

/// Number of entries of the parameter vector.
pub const N_PARAMS: usize = 22;

/// Parameter names in vector order (SI units; see docs/architecture.md, Contract 1).
pub const PARAM_NAMES: [&str; N_PARAMS] = [
    "motor_inertia",
    "damping",
    "coulomb",
    "coulomb_asym",
    "stribeck_torque",
    "stribeck_velocity",
    "load_coulomb",
    "angle_offset",
    "quadratic_drag",
    "cogging_amplitude",
    "cogging_period",
    "cogging_phase",
    "time_delay",
    "torque_bias",
    "torque_drift",
    "tanh_k",
    "torque_gain",
    "spring_stiffness",
    "spring_neutral",
    "friction_ripple_amplitude",
    "friction_ripple_period",
    "friction_ripple_phase",
];

/// Physical parameters of a joint (motor + gearbox); the load is separate (`Load`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Params {
    /// kg·m², the motor's own inertia reflected at the output.
    pub motor_inertia: f64,
    /// N·m·s/rad, viscous damping.
    pub damping: f64,
    /// N·m, Coulomb friction level.
    pub coulomb: f64,
    /// N·m, added to the Coulomb level for positive motion and subtracted for negative.
    pub coulomb_asym: f64,
    /// N·m, extra friction at zero speed (breakaway), decaying as exp(−(ω/v_s)²).
    pub stribeck_torque: f64,
    /// rad/s, the Stribeck velocity v_s.
    pub stribeck_velocity: f64,
    /// Dimensionless: Coulomb grows by this fraction of the load torque on the gearbox.
    pub load_coulomb: f64,
    /// rad, the true hanging-down angle in measured coordinates.
    pub angle_offset: f64,
    /// N·m·s²/rad², drag ∝ ω·|ω|.
    pub quadratic_drag: f64,
    /// N·m, amplitude of the position-periodic ripple.
    pub cogging_amplitude: f64,
    /// Cycles per revolution of the ripple.
    pub cogging_period: f64,
    /// rad, phase of the ripple.
    pub cogging_phase: f64,
    /// s, the applied torque acts this late.
    pub time_delay: f64,
    /// N·m, offset of the measured applied torque.
    pub torque_bias: f64,
    /// N·m/s, linear drift of the measured applied torque.
    pub torque_drift: f64,
    /// s/rad, steepness of the thesis's tanh friction.
    pub tanh_k: f64,
    /// Dimensionless scale of the measured applied torque: the torque that acts is
    /// `torque_gain · τ_measured` (a driver whose current-based estimate reads high).
    pub torque_gain: f64,
    /// N·m/rad, an elastic torque −k·(θ − neutral): a cable, a hose, a return spring.
    pub spring_stiffness: f64,
    /// rad, the angle where the spring is relaxed.
    pub spring_neutral: f64,
    /// N·m, amplitude of a Coulomb level periodic in the angle (gear-mesh friction).
    pub friction_ripple_amplitude: f64,
    /// Cycles per revolution of the friction ripple.
    pub friction_ripple_period: f64,
    /// rad, phase of the friction ripple.
    pub friction_ripple_phase: f64,
}

impl Default for Params {
    /// The defaults of Contract 1; `motor_inertia` has none there, so it is 0 here and
    /// `validate` refuses it until it is set.
    fn default() -> Self {
        Params {
            motor_inertia: 0.0,
            damping: 0.0,
            coulomb: 0.0,
            coulomb_asym: 0.0,
            stribeck_torque: 0.0,
            stribeck_velocity: 0.1,
            load_coulomb: 0.0,
            angle_offset: 0.0,
            quadratic_drag: 0.0,
            cogging_amplitude: 0.0,
            cogging_period: 0.0,
            cogging_phase: 0.0,
            time_delay: 0.0,
            torque_bias: 0.0,
            torque_drift: 0.0,
            tanh_k: 100.0,
            torque_gain: 1.0,
            spring_stiffness: 0.0,
            spring_neutral: 0.0,
            friction_ripple_amplitude: 0.0,
            friction_ripple_period: 0.0,
            friction_ripple_phase: 0.0,
        }
    }
}

impl Params {
    /// Reads a vector in `PARAM_NAMES` order; the length must be exactly `N_PARAMS`.
    pub fn from_slice(v: &[f64]) -> Result<Self, PlantError> {
        let a: [f64; N_PARAMS] = v.try_into().map_err(|_| {
            PlantError::Shape(format!("a parameter vector has {N_PARAMS} entries, got {}", v.len()))
        })?;
        Ok(Params {
            motor_inertia: a[0],
            damping: a[1],
            coulomb: a[2],
            coulomb_asym: a[3],
            stribeck_torque: a[4],
            stribeck_velocity: a[5],
            load_coulomb: a[6],
            angle_offset: a[7],
            quadratic_drag: a[8],
            cogging_amplitude: a[9],
            cogging_period: a[10],
            cogging_phase: a[11],
            time_delay: a[12],
            torque_bias: a[13],
            torque_drift: a[14],
            tanh_k: a[15],
            torque_gain: a[16],
            spring_stiffness: a[17],
            spring_neutral: a[18],
            friction_ripple_amplitude: a[19],
            friction_ripple_period: a[20],
            friction_ripple_phase: a[21],
        })
    }

    /// The vector in `PARAM_NAMES` order.
    pub fn to_array(&self) -> [f64; N_PARAMS] {
        [
            self.motor_inertia,
            self.damping,
            self.coulomb,
            self.coulomb_asym,
            self.stribeck_torque,
            self.stribeck_velocity,
            self.load_coulomb,
            self.angle_offset,
            self.quadratic_drag,
            self.cogging_amplitude,
            self.cogging_period,
            self.cogging_phase,
            self.time_delay,
            self.torque_bias,
            self.torque_drift,
            self.tanh_k,
            self.torque_gain,
            self.spring_stiffness,
            self.spring_neutral,
            self.friction_ripple_amplitude,
            self.friction_ripple_period,
            self.friction_ripple_phase,
        ]
    }

    /// Refuses values that would make the simulation meaningless or produce NaN: non-finite
    /// entries, a non-positive motor inertia, a non-positive torque gain (a sensor that reads
    /// zero or reversed torque is a wiring error, not a plant), and a Stribeck term without a
    /// positive velocity.
    ///
    /// Negative damping or friction coefficients are allowed on purpose: finite-difference
    /// Jacobians probe just below zero, and the friction level is clipped at 0 anyway.
    pub fn validate(&self) -> Result<(), PlantError> {
        for (name, value) in PARAM_NAMES.iter().zip(self.to_array()) {
            require_finite(name, value)?;
        }
        if self.motor_inertia <= 0.0 {
            return Err(PlantError::InvalidValue(format!(
                "motor_inertia must be > 0, got {}",
                self.motor_inertia
            )));
        }
        if self.torque_gain <= 0.0 {
            return Err(PlantError::InvalidValue(format!(
                "torque_gain must be > 0, got {}",
                self.torque_gain
            )));
        }
        if self.stribeck_torque != 0.0 && self.stribeck_velocity <= 0.0 {
            return Err(PlantError::InvalidValue(format!(
                "stribeck_velocity must be > 0 when stribeck_torque is set, got {}",
                self.stribeck_velocity
            )));
        }
        Ok(())
    }
}

/// The index of a parameter name in the vector, if it is one.
pub fn param_index(name: &str) -> Option<usize> {
    PARAM_NAMES.iter().position(|n| *n == name)
}
