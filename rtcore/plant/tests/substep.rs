//! Property: the plant's substep (`model::step`, built on `model::Substep`, which skips absent
//! terms and takes h/I once per interval) gives the numbers of the full formula, every term
//! computed, to the bit (up to the sign of a zero, which nothing downstream can tell apart).
//!
//! `full_formula_step` is a TEST ORACLE: Contract 1's substep written out term by term, as the
//! plant computed it before `Substep` (docs/plant.md), with the plant's own sine (`plant::trig`). It is not used by any production path.
mod common;
use common::sparse_params;
use plant::{step, trig, FrictionLaw, Load, Params, State};
use proptest::prelude::*;

/// TEST ORACLE: one semi-implicit Euler substep with every term of Contract 1 computed.
fn full_formula_step(state: &mut State, p: &Params, load: &Load, law: FrictionLaw, tau: f64, t: f64, h: f64) {
    let inertia = p.motor_inertia + load.inertia;
    let omega = state.omega;
    let dissipation = p.damping + p.quadratic_drag * omega.abs();
    let tau_corrected = p.torque_gain * tau - p.torque_bias - p.torque_drift * t;
    let gravity = load.gravity_torque * trig::sin(state.theta - p.angle_offset);
    let cogging = if p.cogging_amplitude != 0.0 {
        p.cogging_amplitude * trig::sin(p.cogging_period * state.theta + p.cogging_phase)
    } else {
        0.0
    };
    let spring = p.spring_stiffness * (state.theta - p.spring_neutral);
    let drive = tau_corrected - gravity - cogging - spring;
    let v = if omega != 0.0 { omega } else { drive };
    let direction = if v > 0.0 { 1.0 } else if v < 0.0 { -1.0 } else { 0.0 };
    let mut level = p.coulomb + direction * p.coulomb_asym;
    if p.friction_ripple_amplitude != 0.0 {
        level += p.friction_ripple_amplitude * trig::sin(p.friction_ripple_period * state.theta + p.friction_ripple_phase);
    }
    if p.stribeck_torque != 0.0 {
        let r = omega / p.stribeck_velocity;
        level += p.stribeck_torque * trig::exp(-r * r);
    }
    if p.load_coulomb != 0.0 {
        level += p.load_coulomb * (gravity - tau_corrected).abs();
    }
    let level = level.max(0.0);
    let gain = h / inertia;
    let free = omega + gain * drive;
    let numerator = match law {
        FrictionLaw::Stick => {
            if free.abs() <= gain * level {
                state.omega = 0.0;
                state.theta += h * state.omega;
                return;
            }
            free - free.signum() * gain * level
        }
        FrictionLaw::Tanh => free - gain * level * (p.tanh_k * omega).tanh(),
    };
    state.omega = numerator / (1.0 + gain * dissipation);
    state.theta += h * state.omega;
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    #[test]
    fn the_substep_is_the_full_formula(
        p in sparse_params(),
        tanh in any::<bool>(),
        load_inertia in 0.0..0.05f64,
        gravity in -3.0..3.0f64,
        theta in -3.0..3.0f64,
        omega in prop_oneof![Just(0.0), -10.0..10.0f64],
        tau in prop_oneof![Just(0.0), -2.0..2.0f64],
        t in 0.0..20.0f64,
        h in 1e-5..2e-3f64,
        steps in 1usize..40,
    ) {
        let law = if tanh { FrictionLaw::Tanh } else { FrictionLaw::Stick };
        let load = Load { inertia: load_inertia, gravity_torque: gravity };
        let (mut fast, mut full) = (State { theta, omega }, State { theta, omega });
        for k in 0..steps {
            let tk = t + k as f64 * h;
            step(&mut fast, &p, &load, law, tau, tk, h);
            full_formula_step(&mut full, &p, &load, law, tau, tk, h);
            // == on f64: equal bits, except that 0.0 == -0.0.
            prop_assert!(fast.theta == full.theta && fast.omega == full.omega,
                "substep {k}: {fast:?} against {full:?}");
        }
    }
}
