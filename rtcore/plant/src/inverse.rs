//! The model read backwards: the torque that makes the joint move a given way.
//!
//! `admittance predict` compares a measured torque with the torque the model needs for the
//! recorded (filtered) motion. That is the plant equation solved for the applied torque, and it
//! lives here, beside the forward model, so the two cannot drift apart (one source of physics):
//!
//! `τ_c = I·ω' + G·sin(θ − offset) + cogging(θ) + spring(θ) + B·ω + c·ω|ω| + level·shape(ω)`
//!
//! with the level of `friction::level` (load-dependent Coulomb taken at the load torque to
//! first order, `τ_c ≈ everything but friction`), and `shape` = sgn ω beyond `velocity_eps`
//! (0 inside it, where the sign of a filtered velocity is noise and a sticking joint's friction
//! is whatever holds it) for the stick law, tanh(k·ω) for the thesis's law.
//!
//! `corrected_torque` is the other side of the comparison: a measured torque as the model sees
//! it, `torque_gain·τ(t − time_delay) − torque_bias − torque_drift·(t − t₀)`, interpolated like
//! the simulator interpolates it.
use crate::error::{require_finite, PlantError};
use crate::friction::{self, FrictionLaw};
use crate::model::{static_torques, Load, StaticTorques};
use crate::params::Params;
use crate::trial::TorqueSeries;

/// The corrected applied torque (N·m) that gives acceleration `alpha` at (`theta`, `omega`).
#[allow(clippy::too_many_arguments)]
pub fn required_torque(
    p: &Params,
    load: &Load,
    law: FrictionLaw,
    theta: f64,
    omega: f64,
    alpha: f64,
    velocity_eps: f64,
) -> f64 {
    let inertia = p.motor_inertia + load.inertia;
    let StaticTorques { gravity, cogging, spring } = static_torques(p, load, theta);
    let applied =
        inertia * alpha + gravity + cogging + spring + p.damping * omega + p.quadratic_drag * omega * omega.abs();
    // At ω = 0 the level's direction comes from the drive; the shape is 0 there anyway.
    let level = friction::level(p, theta, omega, applied, gravity - applied);
    let shape = match law {
        FrictionLaw::Tanh => (p.tanh_k * omega).tanh(),
        FrictionLaw::Stick if omega.abs() > velocity_eps => omega.signum(),
        FrictionLaw::Stick => 0.0,
    };
    applied + level * shape
}

/// `required_torque` along a recorded motion; the arrays must have one length.
#[allow(clippy::too_many_arguments)]
pub fn required_torques(
    p: &Params,
    load: &Load,
    law: FrictionLaw,
    theta: &[f64],
    omega: &[f64],
    alpha: &[f64],
    velocity_eps: f64,
) -> Result<Vec<f64>, PlantError> {
    p.validate()?;
    require_finite("velocity_eps", velocity_eps)?;
    if omega.len() != theta.len() || alpha.len() != theta.len() {
        return Err(PlantError::Shape(format!(
            "theta, omega and alpha must have one length, got {}, {} and {}",
            theta.len(),
            omega.len(),
            alpha.len()
        )));
    }
    for (name, values) in [("theta", theta), ("omega", omega), ("alpha", alpha)] {
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(PlantError::InvalidValue(format!("{name}[{i}] must be finite, got {}", values[i])));
        }
    }
    Ok(theta
        .iter()
        .zip(omega)
        .zip(alpha)
        .map(|((&th, &om), &al)| required_torque(p, load, law, th, om, al, velocity_eps))
        .collect())
}

/// A measured torque series as the model sees it at the series' own times.
pub fn corrected_torque(p: &Params, t: &[f64], tau: &[f64]) -> Result<Vec<f64>, PlantError> {
    p.validate()?;
    let mut series = TorqueSeries::new(t, tau)?;
    let t0 = t[0];
    Ok(t.iter()
        .map(|&tk| p.torque_gain * series.at(tk - p.time_delay) - p.torque_bias - p.torque_drift * (tk - t0))
        .collect())
}
