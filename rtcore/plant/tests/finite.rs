//! Property: bounded parameters, torques and initial states never produce NaN or inf.
mod common;
use plant::{FrictionLaw, Load, Params, State, Trial};
use proptest::prelude::*;

fn params() -> impl Strategy<Value = Params> {
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
