//! Forward sensitivities against the plant itself: the angle row is the simulator's, bit for
//! bit, and every derivative row is what central differences of the simulator give.
mod common;
use common::*;
use plant::{FrictionLaw, Load, Params, PlantError, Sensitivities, State, Trial, N_PARAMS, PARAM_NAMES};
use proptest::prelude::*;

const STEP: f64 = 1e-3;

fn driven_trial(duration: f64) -> Trial {
    let t = times(duration, 1.0 / 120.0);
    let tau: Vec<f64> = t.iter().map(|x| 0.3 * (2.1 * x).sin() + 0.1 * (7.3 * x).cos()).collect();
    Trial::new(t, Some(tau), Load { inertia: 2e-3, gravity_torque: 0.4 }).unwrap()
}

fn drop_trial(duration: f64) -> Trial {
    Trial::new(times(duration, 1.0 / 120.0), None, Load { inertia: 3e-3, gravity_torque: 0.5 }).unwrap()
}

/// Every effect switched on, each small enough that the motion stays a pendulum's.
fn all_effects() -> Params {
    Params {
        motor_inertia: 0.0147,
        damping: 0.03,
        coulomb: 0.02,
        coulomb_asym: 0.004,
        stribeck_torque: 0.01,
        stribeck_velocity: 0.4,
        load_coulomb: 0.02,
        angle_offset: 0.03,
        quadratic_drag: 0.002,
        cogging_amplitude: 0.005,
        cogging_period: 6.0,
        cogging_phase: 0.4,
        time_delay: 0.012,
        torque_bias: 0.01,
        torque_drift: 0.001,
        tanh_k: 30.0,
        torque_gain: 1.1,
        spring_stiffness: 0.05,
        spring_neutral: 0.2,
        friction_ripple_amplitude: 0.003,
        friction_ripple_period: 5.0,
        friction_ripple_phase: 0.7,
    }
}

fn sensitivities(trial: &Trial, p: &Params, law: FrictionLaw, x0: State, wrt: &[usize]) -> Vec<f64> {
    let trials = [trial];
    let request = Sensitivities { trials: &trials, params: p, x0: &[x0], wrt, law, max_step: STEP, threads: Some(1) };
    request.run().unwrap().remove(0)
}

/// ∂θ/∂(parameter j) by central differences of the simulator, at a relative step `rel`.
fn difference(trial: &Trial, p: &Params, law: FrictionLaw, x0: State, j: usize, rel: f64) -> Vec<f64> {
    let value = p.to_array()[j];
    let eps = rel * value.abs().max(1e-2);
    let shifted = |delta: f64| {
        let mut v = p.to_array();
        v[j] += delta;
        thetas(&run(trial, &Params::from_slice(&v).unwrap(), law, x0, STEP))
    };
    let (up, down) = (shifted(eps), shifted(-eps));
    up.iter().zip(&down).map(|(a, b)| (a - b) / (2.0 * eps)).collect()
}

fn x0_difference(trial: &Trial, p: &Params, law: FrictionLaw, x0: State, omega: bool) -> Vec<f64> {
    let eps = 1e-6;
    let shifted = |delta: f64| {
        let start = if omega { at(x0.theta, x0.omega + delta) } else { at(x0.theta + delta, x0.omega) };
        thetas(&run(trial, p, law, start, STEP))
    };
    let (up, down) = (shifted(eps), shifted(-eps));
    up.iter().zip(&down).map(|(a, b)| (a - b) / (2.0 * eps)).collect()
}

/// The largest difference between two rows, relative to the larger row's size.
fn mismatch(a: &[f64], b: &[f64]) -> f64 {
    let size = a.iter().chain(b).fold(0.0f64, |m, v| m.max(v.abs()));
    let worst = a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    if size == 0.0 {
        worst
    } else {
        worst / size
    }
}

fn row(out: &[f64], n: usize, r: usize) -> &[f64] {
    &out[r * n..(r + 1) * n]
}

fn all_params() -> Vec<usize> {
    (0..N_PARAMS).collect()
}

#[test]
fn the_angle_row_is_the_simulators_own_bit_for_bit() {
    let p = all_effects();
    for law in [FrictionLaw::Stick, FrictionLaw::Tanh] {
        for trial in [driven_trial(3.0), drop_trial(3.0)] {
            let x0 = at(1.2, -0.5);
            let out = sensitivities(&trial, &p, law, x0, &all_params());
            assert_eq!(row(&out, trial.n_samples(), 0), thetas(&run(&trial, &p, law, x0, STEP)).as_slice());
        }
    }
}

#[test]
fn every_derivative_matches_central_differences_on_a_smooth_law() {
    // The tanh law is smooth in the velocity: away from the kinks of |ω| and of the direction
    // (a measure-zero set the differences rarely straddle) the map is differentiable.
    let p = all_effects();
    let trial = driven_trial(2.0);
    let x0 = at(1.0, 0.3);
    let n = trial.n_samples();
    let out = sensitivities(&trial, &p, FrictionLaw::Tanh, x0, &all_params());
    for (j, name) in PARAM_NAMES.iter().enumerate() {
        let fd = difference(&trial, &p, FrictionLaw::Tanh, x0, j, 1e-6);
        let m = mismatch(row(&out, n, j + 1), &fd);
        assert!(m < 1e-4, "{name}: mismatch {m:.2e}");
    }
    for (r, omega) in [(N_PARAMS + 1, false), (N_PARAMS + 2, true)] {
        let m = mismatch(row(&out, n, r), &x0_difference(&trial, &p, FrictionLaw::Tanh, x0, omega));
        assert!(m < 1e-4, "x0 (omega {omega}): mismatch {m:.2e}");
    }
}

#[test]
fn stick_law_derivatives_match_differences_through_slipping_and_sticking() {
    // A drop that swings, slows and sticks: the derivative is the one of the branch taken.
    let p = Params { coulomb: 0.06, stribeck_torque: 0.02, stribeck_velocity: 0.3, quadratic_drag: 0.003, ..all_effects() };
    let trial = drop_trial(6.0);
    let x0 = at(1.3, 0.0);
    let n = trial.n_samples();
    let states = run(&trial, &p, FrictionLaw::Stick, x0, STEP);
    assert_eq!(states[n - 1].omega, 0.0, "the drop must end stuck for this test to mean anything");
    let wrt = [0usize, 1, 2, 4, 5, 7, 8, 17];
    let out = sensitivities(&trial, &p, FrictionLaw::Stick, x0, &wrt);
    for (r, &j) in wrt.iter().enumerate() {
        let fd = difference(&trial, &p, FrictionLaw::Stick, x0, j, 1e-7);
        let m = mismatch(row(&out, n, r + 1), &fd);
        assert!(m < 1e-3, "{}: mismatch {m:.2e}", PARAM_NAMES[j]);
    }
    let m = mismatch(row(&out, n, wrt.len() + 1), &x0_difference(&trial, &p, FrictionLaw::Stick, x0, false));
    assert!(m < 1e-3, "theta0: mismatch {m:.2e}");
}

#[test]
fn a_joint_held_by_friction_does_not_depend_on_the_parameters() {
    // A torque below the Coulomb level: the joint never moves, nothing can move it to first order.
    let trial = constant_torque_trial(0.02, 1.0, 0.01);
    let p = Params { coulomb: 0.05, damping: 0.01, ..bare(0.01) };
    let out = sensitivities(&trial, &p, FrictionLaw::Stick, at(0.0, 0.0), &all_params());
    let n = trial.n_samples();
    for (j, name) in PARAM_NAMES.iter().enumerate() {
        assert!(row(&out, n, j + 1).iter().all(|v| *v == 0.0), "{name}");
    }
    assert!(row(&out, n, N_PARAMS + 1).iter().all(|v| *v == 1.0), "dθ/dθ0 is 1 at rest");
}

#[test]
fn torque_parameters_have_no_effect_without_a_measured_torque() {
    let trial = drop_trial(2.0);
    let out = sensitivities(&trial, &all_effects(), FrictionLaw::Stick, at(1.0, 0.0), &[12, 13, 14, 16]);
    let n = trial.n_samples();
    for r in 1..5 {
        assert!(row(&out, n, r).iter().all(|v| *v == 0.0));
    }
}

#[test]
fn parallel_runs_equal_serial_ones() {
    let owned = [driven_trial(1.5), drop_trial(2.0), driven_trial(0.7)];
    let trials: Vec<&Trial> = owned.iter().collect();
    let x0 = [at(1.0, 0.0), at(-0.5, 1.0), at(0.2, 0.0)];
    let p = all_effects();
    let wrt = [0usize, 1, 2, 12];
    let make = |threads| Sensitivities { trials: &trials, params: &p, x0: &x0, wrt: &wrt, law: FrictionLaw::Stick, max_step: STEP, threads };
    let parallel = make(None).run().unwrap();
    assert_eq!(parallel, make(Some(1)).run().unwrap());
    for (k, trial) in owned.iter().enumerate() {
        assert_eq!(parallel[k], sensitivities(trial, &p, FrictionLaw::Stick, x0[k], &wrt));
    }
}

#[test]
fn bad_requests_are_refused_before_running() {
    let owned = [drop_trial(0.5)];
    let trials: Vec<&Trial> = owned.iter().collect();
    let p = all_effects();
    let x0 = [at(0.0, 0.0)];
    let make = |wrt: &'static [usize], x0: &'static [State], params: Params| {
        let params = Box::leak(Box::new(params));
        Sensitivities { trials: &trials, params, x0, wrt, law: FrictionLaw::Stick, max_step: STEP, threads: None }.run()
    };
    let x0: &'static [State] = Box::leak(Box::new(x0));
    assert!(matches!(make(&[22], x0, p), Err(PlantError::InvalidValue(_))));
    assert!(matches!(make(&[1, 1], x0, p), Err(PlantError::InvalidValue(_))));
    assert!(matches!(make(&[1], &[], p), Err(PlantError::Shape(_))));
    assert!(matches!(make(&[1], x0, Params { motor_inertia: f64::NAN, ..p }), Err(PlantError::InvalidValue(_))));
    assert!(matches!(make(&[1], &[State { theta: f64::INFINITY, omega: 0.0 }], p), Err(PlantError::InvalidValue(_))));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    /// Random pendulums on the smooth law: the base parameters' and the initial state's
    /// derivatives agree with central differences.
    #[test]
    fn random_pendulums_agree_with_differences(
        inertia in 5e-3..5e-2f64,
        damping in 0.0..0.1f64,
        coulomb in 0.0..0.05f64,
        gravity in 0.1..1.0f64,
        theta0 in -1.5..1.5f64,
        omega0 in -2.0..2.0f64,
    ) {
        let p = Params { damping, coulomb, tanh_k: 20.0, ..bare(inertia) };
        let trial = Trial::new(times(1.5, 1.0 / 100.0), None, Load { inertia: 0.0, gravity_torque: gravity }).unwrap();
        let x0 = at(theta0, omega0);
        let n = trial.n_samples();
        let out = sensitivities(&trial, &p, FrictionLaw::Tanh, x0, &[0, 1, 2]);
        for (r, j) in [0usize, 1, 2].into_iter().enumerate() {
            let m = mismatch(row(&out, n, r + 1), &difference(&trial, &p, FrictionLaw::Tanh, x0, j, 1e-6));
            prop_assert!(m < 1e-3, "{}: mismatch {:.2e}", PARAM_NAMES[j], m);
        }
        let m = mismatch(row(&out, n, 5), &x0_difference(&trial, &p, FrictionLaw::Tanh, x0, true));
        prop_assert!(m < 1e-3, "omega0: mismatch {:.2e}", m);
    }
}
