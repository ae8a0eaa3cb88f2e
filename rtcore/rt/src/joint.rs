//! One joint of the loop: user torque → virtual-joint step → limited state → goal tick.
//!
//! Why limits clamp the state, not the output: clipping only the goal lets the model's θ run on
//! past the limit (integrator wind-up); the joint then sticks at the limit until the model comes
//! all the way back, and overshoots the other way (ros2_controllers #1867). Here the velocity
//! change is limited by the acceleration bound, the velocity by its bound, and at a position
//! limit the velocity into the limit is zeroed, so the state itself never leaves the range and
//! responds at once when the user pushes back. A state already outside the range (a limit
//! narrowed live) is not pulled in with a jump: it may only move back towards the range.
//!
//! The bounds are applied with `min`/`max`, never `f64::clamp`: clamp panics on a NaN or on
//! crossed bounds, and the RT thread must not panic whatever reaches it (the parameter gate
//! keeps such values out; this keeps a bug from becoming a dead loop).
use crate::params::{envelope, JointGains, Limits};
use plant::State;
use std::f64::consts::TAU;

/// Joint angle ↔ encoder tick of one servo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickMap {
    /// The tick that is θ = 0.
    pub zero_tick: i64,
    /// +1 or −1: whether θ grows with the tick.
    pub direction: i64,
    pub ticks_per_rev: f64,
    /// The model's goal range (e.g. 0..=4095 for an MX in position mode).
    pub tick_min: i64,
    pub tick_max: i64,
}

impl TickMap {
    /// goal = zero_tick + direction·θ·ticks_per_rev/2π, rounded and clamped to the model's range.
    pub fn goal_tick(&self, theta: f64) -> i64 {
        let ticks = (self.direction as f64 * theta * self.ticks_per_rev / TAU).round();
        let ticks = ticks.clamp(-1e12, 1e12) as i64;
        (self.zero_tick + ticks).clamp(self.tick_min, self.tick_max)
    }

    pub fn theta_of(&self, tick: i64) -> f64 {
        (self.direction * (tick - self.zero_tick)) as f64 * TAU / self.ticks_per_rev
    }

    /// The θ range the tick range allows (the default position limits).
    pub fn theta_range(&self) -> (f64, f64) {
        let (a, b) = (self.theta_of(self.tick_min), self.theta_of(self.tick_max));
        (a.min(b), a.max(b))
    }
}

/// The user's torque on the joint from the conditioned force vector.
pub fn user_torque(force: &[f64; 6], axis: usize, gains: &JointGains) -> f64 {
    force[axis] * gains.lever_arm
}

/// One step of the virtual joint under `tau`, with the state limited; returns the acceleration.
pub fn integrate(state: &mut State, gains: &JointGains, limits: &Limits, tau: f64, h: f64) -> f64 {
    let before = *state;
    plant::admittance::step(state, &gains.admittance(), tau, h);
    let max_dv = limits.acceleration_max * h;
    let mut omega = before.omega + bound(state.omega - before.omega, max_dv);
    omega = bound(omega, limits.velocity_max);
    let mut theta = before.theta + h * omega;
    let hi = limits.position_max.max(before.theta);
    let lo = limits.position_min.min(before.theta);
    if theta > hi {
        theta = hi;
        omega = 0.0;
    } else if theta < lo {
        theta = lo;
        omega = 0.0;
    }
    *state = State { theta, omega };
    (omega - before.omega) / h
}

/// `x` limited to ±`limit`, without `clamp`'s panic on a NaN or a negative limit.
pub(crate) fn bound(x: f64, limit: f64) -> f64 {
    x.min(limit).max(-limit)
}

/// Whether a model state is one the loop can have reached from accepted parameters: finite, θ
/// within the goal range's angles (give or take a turn: a state outside the position limits
/// after they narrowed is legitimate), |ω| within the envelope's speed. Anything else is a
/// bug or a corruption, and the loop holds rather than turn it into a goal.
pub fn state_in_envelope(state: &State, ticks: &TickMap) -> bool {
    let (lo, hi) = ticks.theta_range();
    state.theta.is_finite()
        && state.omega.is_finite()
        && state.theta >= lo - TAU
        && state.theta <= hi + TAU
        && state.omega.abs() <= envelope::VELOCITY_MAX
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gains() -> JointGains {
        JointGains { inertia: 0.01, damping: 0.0, coulomb: 0.0, lever_arm: 0.1 }
    }

    fn wide() -> Limits {
        Limits { position_min: -1e3, position_max: 1e3, velocity_max: 1e3, acceleration_max: 1e6 }
    }

    #[test]
    fn ticks_round_trip_and_clamp_to_the_model_range() {
        let m = TickMap { zero_tick: 2048, direction: -1, ticks_per_rev: 4096.0, tick_min: 0, tick_max: 4095 };
        assert_eq!(m.goal_tick(0.0), 2048);
        assert_eq!(m.goal_tick(TAU / 4.0), 1024);
        assert_eq!(m.goal_tick(-10.0), 4095);
        assert_eq!(m.goal_tick(f64::INFINITY), 0);
        assert!((m.theta_of(1024) - TAU / 4.0).abs() < 1e-12);
        let (lo, hi) = m.theta_range();
        assert!(lo < 0.0 && hi > 0.0 && (hi - lo - 4095.0 * TAU / 4096.0).abs() < 1e-9);
    }

    #[test]
    fn free_joint_under_constant_torque_follows_the_parabola() {
        let (h, tau, g) = (1e-3, 0.02, gains());
        let mut s = State::default();
        for _ in 0..1000 {
            integrate(&mut s, &g, &wide(), tau, h);
        }
        // Semi-implicit Euler: θ_n = a·h²·n(n+1)/2 with a = τ/I.
        let a = tau / g.inertia;
        assert!((s.omega - a * 1.0).abs() < 1e-9);
        assert!((s.theta - a * h * h * 1000.0 * 1001.0 / 2.0).abs() < 1e-9);
    }

    #[test]
    fn velocity_and_acceleration_limits_shape_the_state() {
        let limits = Limits { velocity_max: 0.5, acceleration_max: 10.0, ..wide() };
        let mut s = State::default();
        let acc = integrate(&mut s, &gains(), &limits, 1.0, 1e-3);
        assert!((acc - 10.0).abs() < 1e-9);
        for _ in 0..1000 {
            integrate(&mut s, &gains(), &limits, 1.0, 1e-3);
        }
        assert_eq!(s.omega, 0.5);
    }

    #[test]
    fn position_limit_stops_the_state_and_releases_at_once_on_reversal() {
        let limits = Limits { position_max: 0.1, ..wide() };
        let mut s = State::default();
        for _ in 0..2000 {
            integrate(&mut s, &gains(), &limits, 0.05, 1e-3);
        }
        assert_eq!(s, State { theta: 0.1, omega: 0.0 });
        integrate(&mut s, &gains(), &limits, -0.05, 1e-3);
        assert!(s.theta < 0.1 && s.omega < 0.0, "no wind-up to unwind");
    }

    #[test]
    fn nan_limits_do_not_panic() {
        let limits = Limits { velocity_max: f64::NAN, acceleration_max: -1.0, ..wide() };
        let mut s = State::default();
        integrate(&mut s, &gains(), &limits, 1.0, 1e-3); // no panic; the loop's guard judges the result
    }

    #[test]
    fn the_envelope_takes_legitimate_states_and_refuses_garbage() {
        let m = TickMap { zero_tick: 2048, direction: 1, ticks_per_rev: 4096.0, tick_min: 0, tick_max: 4095 };
        assert!(state_in_envelope(&State { theta: 3.1, omega: -20.0 }, &m));
        for bad in [State { theta: f64::NAN, omega: 0.0 }, State { theta: 0.0, omega: f64::INFINITY },
                    State { theta: 1e300, omega: 0.0 }, State { theta: 0.0, omega: 1e3 }] {
            assert!(!state_in_envelope(&bad, &m), "{bad:?}");
        }
    }

    #[test]
    fn a_state_outside_a_narrowed_range_does_not_jump() {
        let limits = Limits { position_max: 0.1, ..wide() };
        let mut s = State { theta: 0.5, omega: 0.0 };
        integrate(&mut s, &gains(), &limits, 0.05, 1e-3);
        assert_eq!(s.theta, 0.5);
        integrate(&mut s, &gains(), &limits, -0.05, 1e-3);
        assert!(s.theta < 0.5 && s.theta > 0.49);
    }
}
