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

#[test]
fn spring_pulls_to_its_neutral_angle_at_its_own_frequency() {
    let k = 0.08;
    let p = Params { spring_stiffness: k, spring_neutral: 0.2, ..bare(I) };
    let trial = constant_torque_trial(0.0, 2.0, 0.001);
    let resting = run(&trial, &p, FrictionLaw::Stick, at(0.2, 0.0), 1e-5);
    assert!(resting.iter().all(|s| (s.theta - 0.2).abs() < 1e-12), "relaxed at its neutral angle");
    let states = run(&trial, &p, FrictionLaw::Stick, at(0.3, 0.0), 1e-5);
    assert!(states[1].omega < 0.0, "pulls back towards the neutral angle");
    // Undamped oscillator about 0.2: θ = 0.2 + 0.1·cos(√(k/I)·t).
    let w = (k / I).sqrt();
    for (i, s) in states.iter().enumerate().step_by(97) {
        let exact = 0.2 + 0.1 * (w * i as f64 * 0.001).cos();
        assert!((s.theta - exact).abs() < 2e-3, "t = {} s: {} vs {exact}", i as f64 * 0.001, s.theta);
    }
}

#[test]
fn friction_ripple_holds_the_joint_where_its_level_is_high_only() {
    // Level 0.05 ± 0.02 with the angle (6 per revolution); a torque of 0.06 breaks it loose
    // where the level is 0.03 (sin = −1) but not where it is 0.07 (sin = +1).
    let p = Params {
        coulomb: 0.05,
        friction_ripple_amplitude: 0.02,
        friction_ripple_period: 6.0,
        friction_ripple_phase: 0.0,
        ..bare(I)
    };
    let trial = constant_torque_trial(0.06, 0.05, 0.001);
    let quarter = std::f64::consts::PI / 12.0; // 6θ = π/2: the level's peak
    let held = run(&trial, &p, FrictionLaw::Stick, at(quarter, 0.0), H);
    assert!(held.iter().all(|s| s.theta == quarter), "level 0.07 > 0.06: stuck");
    let slips = run(&trial, &p, FrictionLaw::Stick, at(-quarter, 0.0), H);
    assert!(slips.last().unwrap().theta > -quarter + 1e-4, "level 0.03 < 0.06: moves");
    // A ripple is friction: it never pushes. At rest with no torque nothing moves anywhere.
    let none = constant_torque_trial(0.0, 0.5, 0.01);
    for start in [-1.0, -0.3, 0.0, 0.4, 1.2] {
        assert!(run(&none, &p, FrictionLaw::Stick, at(start, 0.0), H).iter().all(|s| s.theta == start));
    }
}

#[test]
fn required_torque_inverts_a_step_of_the_forward_model() {
    // From a moving state, one forward substep under torque τ gives an acceleration α; the
    // inverse model at that state and α returns τ (to first order in the step).
    let p = Params {
        damping: 0.03,
        coulomb: 0.02,
        coulomb_asym: 0.004,
        quadratic_drag: 1e-3,
        cogging_amplitude: 0.004,
        cogging_period: 8.0,
        spring_stiffness: 0.05,
        friction_ripple_amplitude: 0.003,
        friction_ripple_period: 5.0,
        angle_offset: 0.02,
        ..bare(I)
    };
    let load = Load { inertia: 1e-3, gravity_torque: 0.3 };
    for (theta, omega, tau) in [(0.4, 1.5, 0.2), (-0.7, -2.0, -0.1), (0.1, 0.8, 0.0)] {
        let mut s = at(theta, omega);
        let h = 1e-7;
        plant::step(&mut s, &p, &load, FrictionLaw::Stick, tau, 0.0, h);
        let alpha = (s.omega - omega) / h;
        let back = plant::inverse::required_torque(&p, &load, FrictionLaw::Stick, theta, omega, alpha, 1e-3);
        assert!((back - tau).abs() < 1e-4, "θ {theta}, ω {omega}: {back} vs {tau}");
    }
}

#[test]
fn corrected_torque_applies_gain_delay_bias_and_drift() {
    let p = Params { torque_gain: 0.8, torque_bias: 0.01, torque_drift: 0.002, time_delay: 0.5, ..bare(I) };
    let t: Vec<f64> = (0..5).map(|i| i as f64).collect();
    let tau: Vec<f64> = t.iter().map(|x| 2.0 * x).collect();
    let out = plant::inverse::corrected_torque(&p, &t, &tau).unwrap();
    // τ(t − 0.5) = 2t − 1 inside the series (held at τ(0) = 0 before it).
    let expected = [0.0, 1.0, 3.0, 5.0, 7.0].iter().zip(&t).map(|(d, ti)| 0.8 * d - 0.01 - 0.002 * ti);
    for (o, e) in out.iter().zip(expected) {
        assert!((o - e).abs() < 1e-12, "{o} vs {e}");
    }
    assert!(plant::inverse::corrected_torque(&p, &t, &tau[..3]).is_err());
}
