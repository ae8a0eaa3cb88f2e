//! Property: the friction level with the Stribeck term left out beyond `friction::stribeck_cut`
//! is, to the bit, the level with the term always added (`friction::level`, whose Stribeck
//! term is the full formula's: tests/substep.rs). Velocities are drawn around the cut itself,
//! where a cut placed too low would first change a bit.
use plant::friction::{level, level_within, stribeck_cut};
use plant::Params;
use proptest::prelude::*;

/// A Stribeck-only friction (the sets the cut applies to), with probes of either sign.
fn stribeck_params() -> impl Strategy<Value = Params> {
    (-1.0..1.0f64, -1.0..1.0f64, 1e-3..2.0f64, 0.0..0.5f64).prop_map(|(coulomb, stribeck_torque, v, load_coulomb)| Params {
        motor_inertia: 0.01,
        coulomb,
        stribeck_torque,
        stribeck_velocity: v,
        load_coulomb,
        ..Params::default()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]
    #[test]
    fn beyond_the_cut_the_term_changes_no_bit(p in stribeck_params(), around in -12.0..3.0f64, sign in prop::bool::ANY,
                                              load in -2.0..2.0f64) {
        let cut = stribeck_cut(&p);
        prop_assume!(cut.is_finite());
        let r2 = (cut + around).max(0.0);
        let omega = if sign { 1.0 } else { -1.0 } * r2.sqrt() * p.stribeck_velocity;
        let full = level(&p, 0.3, omega, 0.1, load);
        let cut_off = level_within(&p, cut, 0.3, omega, 0.1, load);
        prop_assert_eq!(full.to_bits(), cut_off.to_bits(), "omega {} (r² {} against the cut {})", omega, r2, cut);
    }
}

#[test]
fn a_typical_stribeck_term_is_cut_a_few_velocities_out() {
    // MX-64-like: Coulomb 0.084 N·m, Stribeck 0.04 N·m; the term counts up to ~6.3 v_s.
    let p = Params { coulomb: 0.084, stribeck_torque: 0.04, stribeck_velocity: 0.1, ..Params::default() };
    let cut = stribeck_cut(&p);
    assert!((35.0..45.0).contains(&cut), "cut {cut}");
}

#[test]
fn no_cut_where_the_level_before_the_term_varies_or_is_zero() {
    let base = Params { coulomb: 0.084, stribeck_torque: 0.04, stribeck_velocity: 0.1, ..Params::default() };
    for p in [
        Params { coulomb_asym: 0.01, ..base },
        Params { friction_ripple_amplitude: 0.01, friction_ripple_period: 8.0, ..base },
        Params { coulomb: 0.0, ..base },
        Params { stribeck_torque: 0.0, ..base },
        Params { coulomb: f64::MAX, stribeck_torque: f64::MAX, ..base },
    ] {
        assert_eq!(stribeck_cut(&p), f64::INFINITY, "{p:?}");
    }
}
