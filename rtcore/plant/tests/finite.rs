//! Property: bounded parameters, torques and initial states never produce NaN or inf.
mod common;
use common::params;
use plant::{FrictionLaw, Load, State, Trial};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    #[test]
    fn simulation_stays_finite(
        p in params(),
        tau in prop::collection::vec(-2.0..2.0f64, 2..40),
        load_inertia in 0.0..0.1f64,
        gravity in -2.0..2.0f64,
        theta0 in -4.0..4.0f64,
        omega0 in -20.0..20.0f64,
        tanh in any::<bool>(),
    ) {
        let t: Vec<f64> = (0..tau.len()).map(|i| i as f64 * 0.01).collect();
        let trial = Trial::new(t, Some(tau), Load { inertia: load_inertia, gravity_torque: gravity }).unwrap();
        let law = if tanh { FrictionLaw::Tanh } else { FrictionLaw::Stick };
        let states = plant::simulate(&trial, &p, law, State { theta: theta0, omega: omega0 }, 1e-4).unwrap();
        for s in states {
            prop_assert!(s.theta.is_finite() && s.omega.is_finite(), "{s:?}");
        }
    }
}
