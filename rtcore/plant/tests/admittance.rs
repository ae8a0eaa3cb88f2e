//! The RT loop's virtual joint and its stability gate.
mod common;
use common::at;
use plant::admittance::{check_stable, step, AdmittanceParams};

const H: f64 = 1e-3;
const JOINT: AdmittanceParams = AdmittanceParams { inertia: 0.01, damping: 0.05, coulomb: 0.02 };

fn run(p: &AdmittanceParams, tau: f64, steps: usize, omega0: f64) -> plant::State {
    let mut s = at(0.0, omega0);
    for _ in 0..steps {
        step(&mut s, p, tau, H);
    }
    s
}

#[test]
fn holds_exactly_under_a_sub_threshold_push() {
    let s = run(&JOINT, 0.019, 5000, 0.0);
    assert_eq!((s.theta, s.omega), (0.0, 0.0));
    let s = run(&JOINT, -0.019, 5000, 0.0);
    assert_eq!((s.theta, s.omega), (0.0, 0.0));
}

#[test]
fn reaches_the_steady_velocity_of_the_damper() {
    let s = run(&JOINT, 0.07, 10_000, 0.0);
    let expected = (0.07 - 0.02) / 0.05;
    assert!((s.omega - expected).abs() < 1e-6, "{} vs {expected}", s.omega);
    let s = run(&JOINT, -0.07, 10_000, 0.0);
    assert!((s.omega + expected).abs() < 1e-6);
}

#[test]
fn coasts_to_a_stop_when_released() {
    let s = run(&JOINT, 0.0, 5000, 3.0);
    assert_eq!(s.omega, 0.0);
    assert!(s.theta > 0.0);
}

#[test]
fn stable_parameters_pass_the_gate() {
    assert_eq!(check_stable(&JOINT, H), Ok(()));
    assert_eq!(check_stable(&AdmittanceParams { damping: 0.0, coulomb: 0.0, ..JOINT }, H), Ok(()));
}

#[test]
fn gate_refuses_unsafe_values_with_a_reason() {
    let refused = |p: AdmittanceParams, h: f64, word: &str| {
        let reason = check_stable(&p, h).unwrap_err();
        assert!(reason.contains(word), "{reason:?} should mention {word:?}");
    };
    refused(AdmittanceParams { damping: 10.0, ..JOINT }, H, "h·B/I");
    refused(AdmittanceParams { inertia: 0.0, ..JOINT }, H, "inertia");
    refused(AdmittanceParams { inertia: f64::NAN, ..JOINT }, H, "inertia");
    refused(AdmittanceParams { damping: -0.1, ..JOINT }, H, "damping");
    refused(AdmittanceParams { coulomb: f64::INFINITY, ..JOINT }, H, "coulomb");
    refused(JOINT, 0.0, "step");
}

#[test]
fn the_gate_bound_is_h_b_over_i_equal_one() {
    let under = AdmittanceParams { inertia: 0.01, damping: 0.99 * 0.01 / H, coulomb: 0.0 };
    assert!(check_stable(&under, H).is_ok());
    let at_bound = AdmittanceParams { damping: 0.01 / H, ..under };
    let reason = check_stable(&at_bound, H).unwrap_err();
    assert!(reason.contains("= 1.000 must be < 1"), "{reason}");
}

#[test]
fn damping_beyond_the_gate_still_decays_monotonically() {
    // The gate is about fidelity: the implicit damping itself never rings or diverges.
    let p = AdmittanceParams { inertia: 1e-4, damping: 50.0, coulomb: 0.0 };
    let mut s = at(0.0, 1.0);
    let mut last = s.omega;
    for _ in 0..100 {
        step(&mut s, &p, 0.0, H);
        assert!(s.omega >= 0.0 && s.omega < last);
        last = s.omega;
    }
}
