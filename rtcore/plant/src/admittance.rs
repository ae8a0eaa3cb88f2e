//! The virtual joint of the admittance loop: I·ω' = τ_user − B·ω − friction, no gravity.
//!
//! The real servo follows this joint's angle, so the person feels I, B and F. It uses the
//! plant's own stick-slip code (`friction::advance_velocity`): below F the virtual joint holds
//! exactly still, which the servo then holds too, rather than drifting as a tanh law would.
//!
//! `check_stable` is the gate the RT loop puts in front of parameter changes. The damping is
//! integrated implicitly (ω ← ω/(1 + h·B/I)), which cannot diverge, but it is only faithful
//! while h·B/I is small: the continuous joint decays by e^(−h·B/I) per step, and at h·B/I = 1
//! the step already loses a third of that (1/2 against e^(−1)); beyond, the virtual joint's
//! time constant I/B is shorter than the step and the damping the person feels is set by h,
//! not B. The same bound, h·B/I < 1, also keeps a fully explicit integration (ω ← (1 − h·B/I)·ω)
//! from flipping sign every step, should the loop ever use one. Friction needs no bound: the
//! stick law never reverses the velocity by itself.
use crate::friction::{self, FrictionLaw};
use crate::model::State;

/// The virtual joint's inertia (kg·m²), damping (N·m·s/rad) and Coulomb level (N·m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdmittanceParams {
    pub inertia: f64,
    pub damping: f64,
    pub coulomb: f64,
}

/// Advances the virtual joint by one substep `h` under the user's torque (stick friction).
/// Expects parameters that passed `check_stable`.
#[inline]
pub fn step(state: &mut State, p: &AdmittanceParams, tau_user: f64, h: f64) {
    let omega = state.omega;
    let level = p.coulomb.max(0.0);
    state.omega =
        friction::advance_velocity(omega, p.inertia, tau_user, p.damping, level, FrictionLaw::Stick, 0.0, h);
    state.theta += h * state.omega;
}

/// `Ok(())` when `p` is safe to integrate at step `h`, else the reason with the numbers.
pub fn check_stable(p: &AdmittanceParams, h: f64) -> Result<(), String> {
    if !(h.is_finite() && h > 0.0) {
        return Err(format!("step h must be finite and > 0, got {h}"));
    }
    if !(p.inertia.is_finite() && p.inertia > 0.0) {
        return Err(format!("virtual inertia must be finite and > 0, got {}", p.inertia));
    }
    if !(p.damping.is_finite() && p.damping >= 0.0) {
        return Err(format!("virtual damping must be finite and >= 0, got {}", p.damping));
    }
    if !(p.coulomb.is_finite() && p.coulomb >= 0.0) {
        return Err(format!("virtual coulomb must be finite and >= 0, got {}", p.coulomb));
    }
    let ratio = h * p.damping / p.inertia;
    if ratio >= 1.0 {
        return Err(format!(
            "h·B/I = {h:e} s × {} N·m·s/rad / {} kg·m² = {ratio:.3} must be < 1: the virtual \
             joint's time constant I/B would be shorter than the step; lower the damping below {:.4e} or raise the inertia \
             above {:.4e}",
            p.damping,
            p.inertia,
            p.inertia / h,
            h * p.damping
        ));
    }
    Ok(())
}
