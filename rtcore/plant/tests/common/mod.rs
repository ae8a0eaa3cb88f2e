//! Helpers shared by the integration tests.
#![allow(dead_code)]
use plant::{FrictionLaw, Load, Params, State, Trial};
use proptest::prelude::*;

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

/// Any parameter set within the bounds the fit may probe (every effect, every sign).
pub fn params() -> impl Strategy<Value = Params> {
    (
        (1e-7..1e-1f64, 0.0..10.0f64, 0.0..1.0f64, -0.5..0.5f64, 0.0..1.0f64, 1e-3..10.0f64),
        (0.0..2.0f64, -0.5..0.5f64, 0.0..1.0f64, 0.0..0.5f64, 0.0..50.0f64, -3.0..3.0f64),
        (0.0..0.1f64, -1.0..1.0f64, -1.0..1.0f64, 0.0..1e4f64, 0.05..5.0f64),
        (0.0..10.0f64, -3.0..3.0f64, -0.5..0.5f64, 0.0..50.0f64, -3.0..3.0f64),
    )
        .prop_map(|((mi, b, c, ca, st, sv), (lc, off, qd, ca_, cp, cph), (d, tb, td, k, tg), (ks, kn, ra, rp, rph))| Params {
            motor_inertia: mi,
            damping: b,
            coulomb: c,
            coulomb_asym: ca,
            stribeck_torque: st,
            stribeck_velocity: sv,
            load_coulomb: lc,
            angle_offset: off,
            quadratic_drag: qd,
            cogging_amplitude: ca_,
            cogging_period: cp,
            cogging_phase: cph,
            time_delay: d,
            torque_bias: tb,
            torque_drift: td,
            tanh_k: k,
            torque_gain: tg,
            spring_stiffness: ks,
            spring_neutral: kn,
            friction_ripple_amplitude: ra,
            friction_ripple_period: rp,
            friction_ripple_phase: rph,
        })
}

/// `params()` with a random subset of the optional terms switched off exactly (a spring of
/// stiffness 0, no asymmetry, no cogging, no ripple, no Stribeck, no load-dependent level, an
/// uncorrected torque, no offset), as the fit's models have them: most terms are absent.
pub fn sparse_params() -> impl Strategy<Value = Params> {
    // A third of the draws have every optional term absent (the plant's plain path), a third
    // all but one, a third any mix; bit 10 probes a friction level below zero (validate allows it).
    let level_sign = |below: bool| if below { u16::MAX } else { u16::MAX & !(1 << 10) };
    let all_absent = any::<bool>().prop_map(level_sign);
    let all_but_one = (0..10u16, any::<bool>()).prop_map(move |(bit, below)| level_sign(below) & !(1 << bit));
    (params(), prop_oneof![all_absent, all_but_one, any::<u16>()]).prop_map(|(p, off)| {
        let mut p = p;
        for (bit, switch) in SWITCHES.iter().enumerate() {
            if off & (1 << bit) != 0 {
                switch(&mut p);
            }
        }
        p
    })
}

/// What bit i of `sparse_params`'s mask does: terms 0–9 switched off, each alone (a torque is
/// left uncorrected only when gain, bias and drift are all absent); bit 10 a level below zero.
const SWITCHES: [fn(&mut Params); 11] = [
    |p| p.spring_stiffness = 0.0,
    |p| p.coulomb_asym = 0.0,
    |p| p.cogging_amplitude = 0.0,
    |p| p.friction_ripple_amplitude = 0.0,
    |p| p.stribeck_torque = 0.0,
    |p| p.load_coulomb = 0.0,
    |p| p.torque_gain = 1.0,
    |p| p.torque_bias = 0.0,
    |p| p.torque_drift = 0.0,
    |p| p.angle_offset = 0.0,
    |p| p.coulomb = -p.coulomb,
];
