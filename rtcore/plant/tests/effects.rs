//! One test per optional effect of Contract 1: its sign and its behaviour.
mod common;
use common::*;
use plant::{FrictionLaw, Load, Params, Trial};

const I: f64 = 2e-3;
const H: f64 = 5e-4;

fn gravity_trial(g: f64, duration: f64) -> Trial {
    Trial::new(times(duration, 0.01), None, Load { inertia: 0.0, gravity_torque: g }).unwrap()
}

#[test]
fn stribeck_holds_a_torque_that_coulomb_alone_lets_through() {
    let coulomb = Params { coulomb: 0.05, ..bare(I) };
    let stribeck = Params { stribeck_torque: 0.02, stribeck_velocity: 0.1, ..coulomb };
    let trial = constant_torque_trial(0.06, 1.0, 0.01);
    let slips = run(&trial, &coulomb, FrictionLaw::Stick, at(0.0, 0.0), H);
    let holds = run(&trial, &stribeck, FrictionLaw::Stick, at(0.0, 0.0), H);
    assert!(slips.last().unwrap().theta > 0.1);
    assert_eq!(holds.last().unwrap().theta, 0.0);
    // Once sliding fast, the Stribeck excess has decayed: same deceleration as Coulomb alone.
    let spin = constant_torque_trial(0.0, 0.02, 0.01);
    let a = run(&spin, &coulomb, FrictionLaw::Stick, at(0.0, 20.0), H);
    let b = run(&spin, &stribeck, FrictionLaw::Stick, at(0.0, 20.0), H);
    assert!((a[2].omega - b[2].omega).abs() < 1e-9);
}

#[test]
fn asymmetric_coulomb_stops_sooner_in_the_positive_direction() {
    let p = Params { coulomb: 0.05, coulomb_asym: 0.01, ..bare(I) };
    let trial = constant_torque_trial(0.0, 1.0, 0.01);
    let forward = run(&trial, &p, FrictionLaw::Stick, at(0.0, 2.0), H);
    let backward = run(&trial, &p, FrictionLaw::Stick, at(0.0, -2.0), H);
    let (df, db) = (forward.last().unwrap().theta, -backward.last().unwrap().theta);
    assert!(df > 0.0 && db > 0.0);
    // Stop distances I·ω²/(2F) with F = 0.06 forward and 0.04 backward.
    assert!((df / db - 0.04 / 0.06).abs() < 0.02, "forward {df}, backward {db}");
}

#[test]
fn asymmetric_coulomb_at_rest_follows_the_drive() {
    let p = Params { coulomb: 0.05, coulomb_asym: 0.01, ..bare(I) };
    let push = |tau: f64| run(&constant_torque_trial(tau, 0.5, 0.01), &p, FrictionLaw::Stick, at(0.0, 0.0), H);
    assert_eq!(push(0.055).last().unwrap().theta, 0.0, "positive breakaway is 0.06");
    assert!(push(-0.055).last().unwrap().theta < 0.0, "negative breakaway is 0.04");
}

#[test]
fn load_dependent_coulomb_holds_a_loaded_joint() {
    let g = 0.2;
    let plain = Params { coulomb: 0.05, ..bare(I) };
    let loaded = Params { load_coulomb: 0.5, ..plain };
    // At 0.3 rad the gravity torque is 0.059: above 0.05, below 0.05 + 0.5·0.059.
    let trial = gravity_trial(g, 1.0);
    let falls = run(&trial, &plain, FrictionLaw::Stick, at(0.3, 0.0), H);
    let holds = run(&trial, &loaded, FrictionLaw::Stick, at(0.3, 0.0), H);
    assert!(falls.last().unwrap().theta < 0.29);
    assert!(holds.iter().all(|s| s.theta == 0.3));
}

#[test]
fn angle_offset_moves_the_equilibrium() {
    let p = Params { damping: 0.02, angle_offset: 0.1, ..bare(I) };
    let trial = gravity_trial(0.2, 3.0);
    let states = run(&trial, &p, FrictionLaw::Stick, at(0.1, 0.0), H);
    assert!(states.iter().all(|s| s.theta == 0.1), "resting at the offset stays there");
    let settles = run(&trial, &p, FrictionLaw::Stick, at(0.6, 0.0), H);
    assert!((settles.last().unwrap().theta - 0.1).abs() < 1e-3);
}

#[test]
fn quadratic_drag_decays_speed_as_one_over_t() {
    let c = 1e-3;
    let p = Params { quadratic_drag: c, ..bare(I) };
    let trial = constant_torque_trial(0.0, 1.0, 0.01);
    for w0 in [10.0, -10.0] {
        let last = run(&trial, &p, FrictionLaw::Stick, at(0.0, w0), 1e-5).last().copied().unwrap();
        let exact = w0 / (1.0 + c * w0.abs() * 1.0 / I);
        assert!((last.omega - exact).abs() < 1e-3 * exact.abs(), "{} vs {exact}", last.omega);
    }
}

#[test]
fn cogging_pulls_towards_its_detents() {
    let p = Params { cogging_amplitude: 0.01, cogging_period: 8.0, damping: 0.02, ..bare(I) };
    let trial = constant_torque_trial(0.0, 3.0, 0.01);
    let states = run(&trial, &p, FrictionLaw::Stick, at(0.15, 0.0), H);
    assert!(states[1].omega < 0.0, "the ripple torque −A·sin(8θ) points back to 0");
    assert!(states.last().unwrap().theta.abs() < 1e-3, "settles in the detent at 0");
    let detent = run(&trial, &p, FrictionLaw::Stick, at(2.0 * std::f64::consts::PI / 8.0, 0.0), H);
    assert!(detent.last().unwrap().omega.abs() < 1e-9, "a whole period on is another detent");
}

/// θ under a torque step at t = 0.2 s, sampled at 100 Hz, with the given delay.
fn step_response(delay: f64) -> Vec<f64> {
    let t = times(1.0, 0.01);
    let tau: Vec<f64> = t.iter().map(|&x| if x >= 0.2 - 1e-12 { 0.05 } else { 0.0 }).collect();
    let trial = Trial::new(t, Some(tau), Load::default()).unwrap();
    let p = Params { damping: 0.01, coulomb: 0.01, time_delay: delay, ..bare(I) };
    thetas(&run(&trial, &p, FrictionLaw::Stick, at(0.0, 0.0), H))
}

#[test]
fn time_delay_shifts_the_response_by_the_delay() {
    let prompt = step_response(0.0);
    let late = step_response(0.03);
    assert!(late[22] == 0.0 && prompt[22] > 0.0);
    for i in 0..prompt.len() - 3 {
        assert!((late[i + 3] - prompt[i]).abs() < 1e-12, "sample {i}");
    }
}

fn tau_trial(tau: impl Fn(f64) -> f64) -> Trial {
    let t = times(1.0, 0.01);
    let tau = t.iter().map(|&x| tau(x)).collect();
    Trial::new(t, Some(tau), Load { inertia: 0.0, gravity_torque: 0.1 }).unwrap()
}

/// A correction parameter on the measured torque moves the joint exactly as the corrected
/// torque, given directly, moves the uncorrected plant.
fn assert_correction_is(corrected: Params, measured: impl Fn(f64) -> f64, true_torque: impl Fn(f64) -> f64) {
    let base = Params { torque_bias: 0.0, torque_drift: 0.0, torque_gain: 1.0, ..corrected };
    let a = run(&tau_trial(measured), &corrected, FrictionLaw::Stick, at(0.1, 0.0), H);
    let b = run(&tau_trial(true_torque), &base, FrictionLaw::Stick, at(0.1, 0.0), H);
    for (x, y) in a.iter().zip(&b) {
        assert!((x.theta - y.theta).abs() < 1e-9, "{} vs {}", x.theta, y.theta);
    }
}

#[test]
fn torque_bias_acts_as_a_constant_counter_torque() {
    let biased = Params { damping: 0.01, coulomb: 0.01, torque_bias: 0.02, ..bare(I) };
    assert_correction_is(biased, |x| 0.05 * (3.0 * x).sin(), |x| 0.05 * (3.0 * x).sin() - 0.02);
}

#[test]
fn torque_drift_grows_linearly_from_the_first_sample() {
    let drifting = Params { damping: 0.01, torque_drift: 0.03, ..bare(I) };
    assert_correction_is(drifting, |x| 0.05 * (3.0 * x).sin(), |x| 0.05 * (3.0 * x).sin() - 0.03 * x);
}

#[test]
fn torque_gain_scales_the_measured_torque_before_the_bias() {
    let low = Params { damping: 0.01, coulomb: 0.01, torque_gain: 0.85, torque_bias: 0.01, ..bare(I) };
    assert_correction_is(low, |x| 0.05 * (3.0 * x).sin(), |x| 0.85 * 0.05 * (3.0 * x).sin() - 0.01);
}

#[test]
fn torque_gain_must_be_positive_and_finite() {
    for bad in [0.0, -0.5, f64::NAN, f64::INFINITY] {
        let p = Params { torque_gain: bad, ..bare(I) };
        let err = p.validate().unwrap_err().to_string();
        assert!(err.contains("torque_gain"), "{bad}: {err}");
    }
    assert!(Params { torque_gain: 1e-3, ..bare(I) }.validate().is_ok());
}

#[test]
fn bias_drift_and_gain_do_not_act_on_a_free_swing() {
    let base = Params { damping: 0.01, ..bare(I) };
    let corrected = Params { torque_bias: 0.02, torque_drift: 0.01, torque_gain: 0.7, ..base };
    let trial = gravity_trial(0.1, 1.0);
    let a = run(&trial, &base, FrictionLaw::Stick, at(0.4, 0.0), H);
    let b = run(&trial, &corrected, FrictionLaw::Stick, at(0.4, 0.0), H);
    assert_eq!(a, b);
}
