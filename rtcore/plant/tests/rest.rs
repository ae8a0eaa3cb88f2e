//! Property: a drop that comes to rest for good is not stepped further (`model::rests_for_good`),
//! and the samples filled in are the numbers the stepping would have given, to the bit.
//!
//! The oracle is the same drop as a driven trial whose torque is 0 at every sample: the driven
//! path never skips, and with no torque bias or drift it computes the same numbers.
mod common;
use common::params;
use plant::model::rests_for_good;
use plant::{FrictionLaw, Load, Params, State, Trial};
use proptest::prelude::*;

/// Sample times from 0 with a jittered period (the substep's length changes between intervals).
fn jittered_times(n: usize, dt: f64, jitter: &[f64]) -> Vec<f64> {
    let mut t = vec![0.0];
    for i in 1..n {
        t.push(t[i - 1] + dt * (1.0 + 0.3 * jitter[i % jitter.len()]));
    }
    t
}

fn bits(states: &[State]) -> Vec<(u64, u64)> {
    states
        .iter()
        .map(|s| (s.theta.to_bits(), s.omega.to_bits()))
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn a_skipped_rest_gives_the_stepped_numbers(
        p in params(),
        load_inertia in 0.0..0.05f64,
        gravity in -3.0..3.0f64,
        theta0 in -3.0..3.0f64,
        omega0 in -10.0..10.0f64,
        jitter in prop::collection::vec(-1.0..1.0f64, 1..8),
    ) {
        let p = Params { torque_bias: 0.0, torque_drift: 0.0, ..p };
        let t = jittered_times(400, 0.005, &jitter);
        let load = Load { inertia: load_inertia, gravity_torque: gravity };
        let drop = Trial::new(t.clone(), None, load).unwrap();
        let zeros = Trial::new(t.clone(), Some(vec![0.0; t.len()]), load).unwrap();
        let x0 = State { theta: theta0, omega: omega0 };
        let skipped = plant::simulate(&drop, &p, FrictionLaw::Stick, x0, 1e-3).unwrap();
        let stepped = plant::simulate(&zeros, &p, FrictionLaw::Stick, x0, 1e-3).unwrap();
        prop_assert_eq!(bits(&skipped), bits(&stepped));
    }
}

/// MX-64-like: the thesis's pendulum drop with Coulomb friction ends held, and the test says so.
fn held_drop() -> (Params, Load, Vec<State>) {
    let p = Params {
        motor_inertia: 0.0065,
        damping: 0.02,
        coulomb: 0.08,
        ..Params::default()
    };
    let load = Load {
        inertia: 0.01,
        gravity_torque: 0.6,
    };
    let trial = Trial::new((0..2000).map(|i| i as f64 / 200.0).collect(), None, load).unwrap();
    let states = plant::simulate(
        &trial,
        &p,
        FrictionLaw::Stick,
        State {
            theta: 1.2,
            omega: 0.0,
        },
        1e-3,
    )
    .unwrap();
    (p, load, states)
}

#[test]
fn a_drop_held_by_friction_rests_for_good() {
    let (p, load, states) = held_drop();
    let last = states[states.len() - 1];
    assert_eq!(last.omega, 0.0, "{last:?}");
    assert!(
        last.theta.abs() > 1e-3,
        "held off the bottom by friction: {last:?}"
    );
    assert!(rests_for_good(&last, &p, &load, FrictionLaw::Stick, 0.0));
    // Held there from well before the end: the skip has most of the record to save.
    let first_held = states.iter().position(|s| *s == last).unwrap();
    assert!(
        first_held < states.len() / 2,
        "held from sample {first_held} of {}",
        states.len()
    );
}

#[test]
fn a_rest_is_not_for_good_when_the_joint_would_move() {
    let (p, load, states) = held_drop();
    let last = states[states.len() - 1];
    // Moving, tanh friction, a torque beyond the friction's level, a drift in time: no rest.
    assert!(!rests_for_good(
        &State {
            omega: 1e-12,
            ..last
        },
        &p,
        &load,
        FrictionLaw::Stick,
        0.0
    ));
    assert!(!rests_for_good(&last, &p, &load, FrictionLaw::Tanh, 0.0));
    assert!(!rests_for_good(&last, &p, &load, FrictionLaw::Stick, 1.0));
    assert!(!rests_for_good(
        &last,
        &Params {
            torque_drift: 1e-3,
            ..p
        },
        &load,
        FrictionLaw::Stick,
        0.0
    ));
    let slippery = Params { coulomb: 0.0, ..p };
    assert!(!rests_for_good(
        &last,
        &slippery,
        &load,
        FrictionLaw::Stick,
        0.0
    ));
}
