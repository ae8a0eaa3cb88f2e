//! Friction: its level (Coulomb + effects) and the two laws that apply it.
//!
//! **Stick (default).** Coulomb friction is a constraint, not a smooth force: at rest it
//! supplies whatever torque holds the joint, up to its level. Over one substep of length h the
//! torque that would bring the joint exactly to rest is τ_stop = I·ω/h + drive; friction is
//! that torque clipped to ±level. When it is within the level the velocity is set to exactly
//! 0, so a joint under a sub-threshold torque stays put for ever (no creep), and a moving
//! joint can never be pushed *backwards* by friction alone (the clip stops it at 0). This is
//! the implicit ("time-stepping") treatment of the sign function and needs no regularisation.
//! The code compares velocities rather than torques (|ω + (h/I)·drive| ≤ (h/I)·level, the
//! same test multiplied by h/I) so a substep costs one division instead of three.
//!
//! **Tanh (the thesis).** friction = −level·tanh(k·ω), smooth but never zero-velocity: a
//! joint under any torque creeps at about ω ≈ atanh(τ/level)/k. Kept to reproduce the thesis.
//!
//! The plant (`crate::model`) and the virtual joint (`crate::admittance`) both advance their
//! velocity through `advance_velocity`, so the mock's servos, the identification and the
//! admittance loop share one friction code.
use std::str::FromStr;

use crate::error::PlantError;
use crate::params::Params;
use crate::trig;

/// How the friction level is applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrictionLaw {
    /// Exact stick-slip: the joint stops and stays when the net torque is below the level.
    #[default]
    Stick,
    /// The thesis's smooth −level·tanh(k·ω).
    Tanh,
}

impl FromStr for FrictionLaw {
    type Err = PlantError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        match name {
            "stick" => Ok(FrictionLaw::Stick),
            "tanh" => Ok(FrictionLaw::Tanh),
            other => Err(PlantError::UnknownFrictionLaw(other.to_string())),
        }
    }
}

impl FrictionLaw {
    pub fn name(self) -> &'static str {
        match self {
            FrictionLaw::Stick => "stick",
            FrictionLaw::Tanh => "tanh",
        }
    }
}

/// Direction of motion for the asymmetric level: that of ω, or at rest that of the drive.
#[inline]
pub(crate) fn direction(omega: f64, drive: f64) -> f64 {
    let v = if omega != 0.0 { omega } else { drive };
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// The friction level (≥ 0) at angle `theta` and velocity `omega`, given the
/// velocity-independent torque `drive` and the load torque carried by the gearbox (for
/// load-dependent Coulomb).
///
/// Clipped at 0 so that parameter probes below zero give "no friction" rather than a
/// friction that pushes the joint.
#[inline]
pub fn level(p: &Params, theta: f64, omega: f64, drive: f64, load_torque: f64) -> f64 {
    level_within(p, f64::INFINITY, theta, omega, drive, load_torque)
}

/// `level`, the Stribeck term left out where (ω/v_s)² exceeds `stribeck_cut`
/// (`stribeck_cut(p)`, or ∞ to always add it): there it cannot change the sum, so the result
/// is `level`'s to the bit, without the exponential (12 % of an identification's CPU on drops
/// with a Stribeck term, perf; docs/plant.md, *The integrator*, the Stribeck term's cut).
#[inline(always)]
pub fn level_within(p: &Params, stribeck_cut: f64, theta: f64, omega: f64, drive: f64, load_torque: f64) -> f64 {
    // Without an asymmetry the direction is not needed (the product would be a signed zero).
    let mut level = if p.coulomb_asym != 0.0 { p.coulomb + direction(omega, drive) * p.coulomb_asym } else { p.coulomb };
    if p.friction_ripple_amplitude != 0.0 {
        level += p.friction_ripple_amplitude * trig::sin(p.friction_ripple_period * theta + p.friction_ripple_phase);
    }
    if p.stribeck_torque != 0.0 {
        let r = omega / p.stribeck_velocity;
        let r2 = r * r;
        // A NaN keeps the term (and its NaN), as before the cut.
        if r2.is_nan() || r2 <= stribeck_cut {
            level += p.stribeck_torque * trig::exp(-r2);
        }
    }
    if p.load_coulomb != 0.0 {
        level += p.load_coulomb * load_torque.abs();
    }
    level.max(0.0)
}

/// The (ω/v_s)² above which adding the Stribeck term S·exp(−(ω/v_s)²) to the level before it,
/// the Coulomb level L, gives L again to the bit; ∞ when there is no such bound (no Stribeck
/// term, L = 0, or a level before it that varies: an asymmetry or a ripple).
///
/// Why it is exact: a sum L + δ rounds to L when |δ| is below half the spacing of the doubles
/// next to L on either side, which is at least a quarter of ulp(|L|) (the spacing halves below
/// a power of two). The cut x₀ = ln(4·|S| / ulp(|L|)) + 1 makes |S|·exp(−x) ≤ e⁻¹·ulp(|L|)/4
/// for x ≥ x₀; the margin e⁻¹ covers the rounding of the logarithm, of the exponential (< 1 ulp)
/// and of the product many times over. With L = 0.084 N·m and S = 0.04 N·m, x₀ ≈ 40: the term
/// is left out above 6.3·v_s.
pub fn stribeck_cut(p: &Params) -> f64 {
    let level = p.coulomb.abs();
    let size = p.stribeck_torque.abs();
    if size == 0.0 || p.coulomb_asym != 0.0 || p.friction_ripple_amplitude != 0.0 || !(level.is_normal() && size.is_finite()) {
        return f64::INFINITY;
    }
    let ulp = f64::from_bits(level.to_bits() + 1) - level;
    if !ulp.is_finite() {
        return f64::INFINITY; // L is the largest double: no spacing above it to round into
    }
    (4.0 * size / ulp).ln() + 1.0
}

/// The velocity after one semi-implicit Euler substep of length `h`.
///
/// `drive` is the sum of the torques that do not depend on the velocity; `dissipation`
/// (N·m·s/rad, ≥ 0) is the velocity-proportional part, B + c·|ω| for viscous and quadratic
/// drag. Dissipation is taken implicitly (at the new velocity, linearised): explicit Euler
/// would need h·dissipation/I < 2 to stay finite, and an optimiser probing a small inertia or
/// a large drag would hit that wall; the implicit form is stable for any dissipation ≥ 0 and
/// agrees with the explicit one to first order.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn advance_velocity(
    omega: f64,
    inertia: f64,
    drive: f64,
    dissipation: f64,
    level: f64,
    law: FrictionLaw,
    tanh_k: f64,
    h: f64,
) -> f64 {
    // Velocity change per unit torque over the substep; loop-invariant in a trial's interval.
    advance_with_gain(omega, h / inertia, drive, dissipation, level, law, tanh_k)
}

/// `advance_velocity` given `gain` = h / inertia, the velocity change per unit torque over the
/// substep (a simulation computes it once per sample interval: a division fewer per substep).
#[inline(always)]
pub fn advance_with_gain(
    omega: f64,
    gain: f64,
    drive: f64,
    dissipation: f64,
    level: f64,
    law: FrictionLaw,
    tanh_k: f64,
) -> f64 {
    let free = omega + gain * drive;
    let numerator = match law {
        FrictionLaw::Stick => {
            // free = (h/I)·τ_stop: the velocity without friction. Dissipation vanishes at rest,
            // so it does not enter the test.
            if free.abs() <= gain * level {
                // Set, not computed: the arithmetic would leave a rounding residue and creep.
                return 0.0;
            }
            free - free.signum() * gain * level
        }
        FrictionLaw::Tanh => free - gain * level * (tanh_k * omega).tanh(),
    };
    numerator / (1.0 + gain * dissipation)
}
