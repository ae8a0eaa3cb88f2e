//! Conversions between SI values and control-table units (protocols.md §3.4).
//!
//! The joint angle θ = 0 (hanging down) is tick 2048, the centre of the encoder, which is
//! also the daemon's default `zero_tick`; increasing ticks are CCW, the positive direction.
use std::f64::consts::TAU;

/// Encoder ticks per revolution (AS5045, 12 bits).
pub const TICKS_PER_REV: f64 = 4096.0;
/// The tick of θ = 0.
pub const CENTRE_TICK: i64 = 2048;
/// rad/s per unit of P2 Present/Goal Velocity and Profile Velocity (0.229 rpm).
pub const P2_VELOCITY_UNIT: f64 = 0.229 * TAU / 60.0;
/// rad/s per unit of P1 Moving Speed / Present Speed (0.114 rpm, MX e-manual).
pub const P1_SPEED_UNIT: f64 = 0.114 * TAU / 60.0;
/// A per-mille unit: P1 Present Load and MX-28(2.0) Present Load are 0.1 % of full scale.
pub const PER_MILLE: f64 = 1000.0;
/// A per-mille magnitude at 1023 with a direction bit at 1024: P1's sign-magnitude encoding.
pub const P1_MAGNITUDE_MAX: i64 = 1023;
/// A of P2 MX-64/106 Present/Goal Current per unit.
pub const P2_CURRENT_UNIT: f64 = 3.36e-3;
/// A per unit of P1 MX-64/106 Current (68), centred at 2048.
pub const P1_CURRENT_UNIT: f64 = 4.5e-3;
/// P2 PWM units at 100 % duty (PWM Limit default).
pub const P2_PWM_FULL: f64 = 885.0;

pub fn rad_to_tick(theta: f64) -> i64 {
    CENTRE_TICK + (theta * TICKS_PER_REV / TAU).round() as i64
}

pub fn tick_to_rad(tick: i64) -> f64 {
    (tick - CENTRE_TICK) as f64 * TAU / TICKS_PER_REV
}

/// P1's sign-magnitude encoding (bit 10 set = CW, i.e. negative), magnitude saturated at 1023.
pub fn sign_magnitude(value: f64) -> i64 {
    let magnitude = (value.abs().round() as i64).min(P1_MAGNITUDE_MAX);
    if value < 0.0 && magnitude > 0 {
        magnitude | 1024
    } else {
        magnitude
    }
}

/// The inverse of `sign_magnitude`.
pub fn from_sign_magnitude(raw: i64) -> f64 {
    let magnitude = (raw & P1_MAGNITUDE_MAX) as f64;
    if raw & 1024 != 0 {
        -magnitude
    } else {
        magnitude
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_and_radians_round_trip_about_the_centre() {
        assert_eq!(rad_to_tick(0.0), 2048);
        assert_eq!(rad_to_tick(std::f64::consts::FRAC_PI_2), 3072);
        assert_eq!(rad_to_tick(-std::f64::consts::PI), 0);
        assert!((tick_to_rad(1024) + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn sign_magnitude_sets_bit_10_for_negative_values() {
        assert_eq!(sign_magnitude(100.4), 100);
        assert_eq!(sign_magnitude(-100.0), 1124);
        assert_eq!(sign_magnitude(-5000.0), 2047);
        assert_eq!(from_sign_magnitude(1124), -100.0);
        assert_eq!(from_sign_magnitude(sign_magnitude(-0.2)), 0.0);
    }
}
