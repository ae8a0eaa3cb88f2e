//! Helpers shared by the integration tests.
#![allow(dead_code)]
use plant::{FrictionLaw, Load, Params, State, Trial};

/// Parameters with only an inertia set: no friction, no effects.
pub fn bare(inertia: f64) -> Params {
    Params { motor_inertia: inertia, ..Params::default() }
}

/// Uniform sample times 0, dt, ..., covering `duration`.
pub fn times(duration: f64, dt: f64) -> Vec<f64> {
    let n = (duration / dt).round() as usize;
    (0..=n).map(|i| i as f64 * dt).collect()
}

/// A trial with a constant applied torque and no gravity.
pub fn constant_torque_trial(tau: f64, duration: f64, dt: f64) -> Trial {
    let t = times(duration, dt);
    let n = t.len();
    Trial::new(t, Some(vec![tau; n]), Load::default()).unwrap()
}

pub fn run(trial: &Trial, p: &Params, law: FrictionLaw, x0: State, max_step: f64) -> Vec<State> {
    plant::simulate(trial, p, law, x0, max_step).unwrap()
}

pub fn thetas(states: &[State]) -> Vec<f64> {
    states.iter().map(|s| s.theta).collect()
}

pub fn at(theta: f64, omega: f64) -> State {
    State { theta, omega }
}
