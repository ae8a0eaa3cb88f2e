//! The base model: energy, convergence, stick versus creep.
mod common;
use common::*;
use plant::{step, FrictionLaw, Load, State};

const I: f64 = 2e-3;
const G: f64 = 0.3;

fn energy(s: &State) -> f64 {
    0.5 * I * s.omega * s.omega + G * (1.0 - s.theta.cos())
}

/// Largest relative energy deviation of a frictionless pendulum over `periods` swings.
fn max_energy_error(h: f64, periods: f64) -> f64 {
    let p = bare(I);
    let load = Load { inertia: 0.0, gravity_torque: G };
    let mut s = at(1.0, 0.0);
    let e0 = energy(&s);
    let period = 2.0 * std::f64::consts::PI * (I / G).sqrt();
    let n = (periods * period / h) as usize;
    let mut worst: f64 = 0.0;
    for k in 0..n {
        step(&mut s, &p, &load, FrictionLaw::Stick, 0.0, k as f64 * h, h);
        worst = worst.max((energy(&s) - e0).abs() / e0);
    }
    worst
}

#[test]
fn energy_is_conserved_without_friction_and_error_shrinks_with_step() {
    let coarse = max_energy_error(1e-3, 200.0);
    let fine = max_energy_error(5e-4, 200.0);
    assert!(coarse < 0.05, "energy error {coarse} over 200 periods");
    // Symplectic Euler: bounded O(h) oscillation, no secular drift.
    assert!(fine < 0.6 * coarse, "halving the step: {coarse} -> {fine}");
    let short = max_energy_error(1e-3, 20.0);
    assert!(coarse < 1.2 * short, "energy drifts: 20 periods {short}, 200 periods {coarse}");
}

#[test]
fn joint_sticks_exactly_below_coulomb() {
    let p = plant::Params { coulomb: 0.05, ..bare(I) };
    let trial = constant_torque_trial(0.049, 2.0, 0.01);
    let states = run(&trial, &p, FrictionLaw::Stick, at(0.3, 0.0), 5e-4);
    assert!(states.iter().all(|s| s.theta == 0.3 && s.omega == 0.0));
}

#[test]
fn joint_moves_above_coulomb_at_the_predicted_acceleration() {
    let p = plant::Params { coulomb: 0.05, ..bare(I) };
    let trial = constant_torque_trial(0.06, 1.0, 0.01);
    let last = *run(&trial, &p, FrictionLaw::Stick, at(0.0, 0.0), 5e-4).last().unwrap();
    let expected = (0.06 - 0.05) / I * 1.0;
    assert!((last.omega - expected).abs() < 1e-9 * expected.max(1.0), "{} vs {expected}", last.omega);
}

#[test]
fn moving_joint_comes_to_a_full_stop() {
    let p = plant::Params { coulomb: 0.05, ..bare(I) };
    let trial = constant_torque_trial(0.0, 1.0, 0.01);
    let states = run(&trial, &p, FrictionLaw::Stick, at(0.0, 2.0), 5e-4);
    let last = states.last().unwrap();
    assert_eq!(last.omega, 0.0);
    let stop_distance = 2.0 * 2.0 * I / (2.0 * 0.05);
    assert!((last.theta - stop_distance).abs() < 2e-3, "{} vs {stop_distance}", last.theta);
}

#[test]
fn tanh_friction_creeps_where_stick_holds() {
    let p = plant::Params { coulomb: 0.05, tanh_k: 100.0, ..bare(I) };
    let trial = constant_torque_trial(0.03, 2.0, 0.01);
    let stick = run(&trial, &p, FrictionLaw::Stick, at(0.0, 0.0), 5e-4);
    let tanh = run(&trial, &p, FrictionLaw::Tanh, at(0.0, 0.0), 5e-4);
    assert_eq!(stick.last().unwrap().theta, 0.0);
    // Creep speed atanh(τ/F)/k ≈ 6.9e-3 rad/s, so ≈ 1.4e-2 rad after 2 s.
    let creep = tanh.last().unwrap().theta;
    let predicted = (0.03f64 / 0.05).atanh() / 100.0 * 2.0;
    assert!((creep - predicted).abs() < 0.1 * predicted, "creep {creep} vs {predicted}");
}

/// θ at the end of a smooth damped, driven pendulum run at substep `h`.
fn smooth_final_angle(h: f64) -> f64 {
    let p = plant::Params { damping: 5e-3, quadratic_drag: 1e-3, ..bare(I) };
    let t = times(1.0, 0.05);
    let tau: Vec<f64> = t.iter().map(|x| 0.1 * (4.0 * x).sin()).collect();
    let trial = plant::Trial::new(t, Some(tau), Load { inertia: 0.0, gravity_torque: G }).unwrap();
    run(&trial, &p, FrictionLaw::Stick, at(0.5, 0.0), h).last().unwrap().theta
}

#[test]
fn error_halves_with_the_step_first_order() {
    let exact = smooth_final_angle(0.05 / 4096.0);
    let errors: Vec<f64> =
        [64.0, 128.0, 256.0].iter().map(|n| (smooth_final_angle(0.05 / n) - exact).abs()).collect();
    for pair in errors.windows(2) {
        let ratio = pair[0] / pair[1];
        assert!((1.7..2.4).contains(&ratio), "error ratio {ratio} ({errors:?})");
    }
}

#[test]
fn non_uniform_sampling_hits_every_sample_time() {
    let p = plant::Params { damping: 5e-3, ..bare(I) };
    let load = Load { inertia: 0.0, gravity_torque: G };
    let uniform = plant::Trial::new(times(1.0, 0.001), None, load).unwrap();
    let picked: Vec<f64> = vec![0.0, 0.013, 0.1, 0.101, 0.5, 0.977, 1.0];
    let sparse = plant::Trial::new(picked.clone(), None, load).unwrap();
    let dense = run(&uniform, &p, FrictionLaw::Stick, at(1.0, 0.0), 1e-5);
    let coarse = run(&sparse, &p, FrictionLaw::Stick, at(1.0, 0.0), 1e-5);
    for (k, tk) in picked.iter().enumerate() {
        let i = (tk / 0.001).round() as usize;
        assert!((dense[i].theta - coarse[k].theta).abs() < 1e-4, "t = {tk}");
    }
}
