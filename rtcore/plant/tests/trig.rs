//! The plant's sine, cosine and exponential (`plant::trig`): the standard library's by default,
//! bit for bit; with the `libm-sine` feature within 1 ulp of them, and not the same function.
use plant::trig;
use proptest::prelude::*;

/// Distance in units in the last place between two finite doubles.
fn ulps(a: f64, b: f64) -> u64 {
    if a == b {
        return 0;
    }
    assert!(a.is_finite() && b.is_finite(), "{a} vs {b}");
    // Map the bits onto a line that is monotonic across zero.
    let key = |x: f64| {
        let bits = x.to_bits() as i64;
        if bits < 0 { i64::MIN - bits } else { bits }
    };
    key(a).abs_diff(key(b))
}

/// The largest difference in ulp from the standard library's sine on a dense grid, and how
/// many arguments differ at all.
fn against_std() -> (u64, usize) {
    let (mut worst, mut differ) = (0, 0);
    let n = 400_000;
    for i in 0..=n {
        let x = -200.0 + 400.0 * i as f64 / n as f64;
        let d = ulps(trig::sin(x), x.sin());
        worst = worst.max(d);
        differ += (d > 0) as usize;
    }
    (worst, differ)
}

#[cfg(not(feature = "libm-sine"))]
#[test]
fn by_default_the_sine_is_the_standard_librarys() {
    assert_eq!(against_std(), (0, 0));
}

#[cfg(feature = "libm-sine")]
#[test]
fn the_libm_sine_is_within_one_ulp_of_the_standard_librarys_and_not_it() {
    let (worst, differ) = against_std();
    assert!(worst <= 1, "worst {worst} ulp");
    assert!(differ > 0, "no difference at all: is the feature compiled in?");
}

#[test]
fn near_multiples_of_a_quarter_turn_the_small_sine_keeps_its_digits() {
    // Cancellation: x close to k·π/2, where a one-step argument reduction would lose them.
    for k in 1..=40 {
        let centre = k as f64 * std::f64::consts::FRAC_PI_2;
        for e in [1e-3, 1e-7, 1e-11] {
            for x in [centre + e, centre - e, centre] {
                assert!(ulps(trig::sin(x), x.sin()) <= 1, "sin({x:e})");
                assert!(ulps(trig::sin_cos(x).1, x.cos()) <= 1, "cos({x:e})");
            }
        }
    }
}

#[test]
fn not_finite_gives_nan_and_a_signed_zero_is_kept() {
    for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        assert!(trig::sin(x).is_nan());
    }
    assert!(trig::sin(-0.0) == 0.0 && trig::sin(-0.0).is_sign_negative());
    assert_eq!(trig::exp(0.0), 1.0);
    assert_eq!(trig::exp(-1e3), 0.0);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn sine_and_cosine_hold_within_one_ulp(x in -1.0e4f64..1.0e4) {
        let (s, c) = trig::sin_cos(x);
        prop_assert_eq!(s.to_bits(), trig::sin(x).to_bits());
        prop_assert!(ulps(s, x.sin()) <= 1, "sin({}) = {} vs {}", x, s, x.sin());
        prop_assert!(ulps(c, x.cos()) <= 1, "cos({}) = {} vs {}", x, c, x.cos());
    }

    #[test]
    fn the_stribeck_exponential_holds_within_one_ulp(r in -40.0f64..40.0) {
        let x = -r * r;
        prop_assert!(ulps(trig::exp(x), x.exp()) <= 1, "exp({}) = {} vs {}", x, trig::exp(x), x.exp());
    }
}
