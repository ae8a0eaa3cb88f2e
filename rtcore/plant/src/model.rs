//! One substep of the pendulum plant (Contract 1).
//!
//! `step` takes the applied torque as a number: the trial simulator (`crate::trial`)
//! interpolates and delays it, the mock bus passes its motor + hand torque directly. The
//! torque-measurement corrections (gain, bias, drift·t) are applied here so every caller that
//! uses them gets the same definition; callers without a measured torque leave them at their
//! defaults (gain 1, bias and drift 0).
use crate::friction::{self, FrictionLaw};
use crate::params::Params;
use crate::trig;

/// What hangs on the joint: its inertia about the axis and its gravity torque amplitude m·g·l.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Load {
    pub inertia: f64,
    pub gravity_torque: f64,
}

/// Joint angle θ (rad, 0 = hanging down) and velocity ω (rad/s).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct State {
    pub theta: f64,
    pub omega: f64,
}

/// The torques that depend on the angle alone. Gravity is kept apart because the friction level
/// of `load_coulomb` reads it; cogging and spring are kept apart so each side adds them in its
/// own order, as before (bit for bit). The simulator (`step`) and the
/// inverse (`crate::inverse`) both take them from here, so the two read Contract 1 once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticTorques {
    pub gravity: f64,
    pub cogging: f64,
    pub spring: f64,
}

#[inline]
pub fn static_torques(p: &Params, load: &Load, theta: f64) -> StaticTorques {
    angle_torques(p, load, theta, true)
}

/// `static_torques`, the spring left at 0 unless `with_spring` (`Substep` adds its own).
#[inline(always)]
fn angle_torques(p: &Params, load: &Load, theta: f64, with_spring: bool) -> StaticTorques {
    let gravity = load.gravity_torque * trig::sin(theta - p.angle_offset);
    let cogging = if p.cogging_amplitude != 0.0 {
        p.cogging_amplitude * trig::sin(p.cogging_period * theta + p.cogging_phase)
    } else {
        0.0
    };
    let spring = if with_spring { p.spring_stiffness * (theta - p.spring_neutral) } else { 0.0 };
    StaticTorques { gravity, cogging, spring }
}

/// Advances `state` by one semi-implicit Euler substep of length `h` (velocity first, then
/// position with the new velocity), under applied torque `tau` at time `t` (the time only
/// enters through `torque_drift`). Damping and quadratic drag act at the new velocity
/// (`friction::advance_velocity`), everything else at the start of the substep.
///
/// Expects validated parameters (`Params::validate`) and `h > 0`; it does not check them
/// because it runs millions of times per identification. A simulation that takes many
/// substeps with one parameter set prepares them once (`Substep`); this is the same substep.
#[inline]
pub fn step(state: &mut State, p: &Params, load: &Load, law: FrictionLaw, tau: f64, t: f64, h: f64) {
    let substep = Substep::once(p, load, law);
    substep.advance(state, tau, t, h / substep.inertia, h);
}

/// One parameter set and load made ready for many substeps: what does not change from one
/// substep to the next is read once (the inertia, and which optional terms are there at all).
///
/// Why: a simulation's cost is its substeps, and an identification runs millions of them;
/// a term that is absent (a spring of stiffness 0, a torque with no correction) is skipped
/// rather than computed as a zero. Skipping is exact: the skipped term is a signed zero, and
/// adding it changes at most the sign of a zero drive or friction level, which no later
/// operation of the substep can tell apart (a zero drive gives no direction and a velocity
/// of exactly 0 at rest; a zero level clips nothing). Tests hold `Substep` to the full
/// formula bit for bit (tests/substep.rs).
#[derive(Clone, Copy)]
pub struct Substep<'a> {
    p: &'a Params,
    load: &'a Load,
    law: FrictionLaw,
    /// Motor plus load inertia; `gain` below is h over it.
    pub inertia: f64,
    /// The measured torque is corrected (gain ≠ 1, or a bias, or a drift).
    corrected: bool,
    spring: bool,
    /// Nothing but gravity, damping, drag and a plain Coulomb level: a drop's base model, the
    /// commonest set of an identification, stepped with one test instead of seven.
    plain: bool,
    /// `friction::stribeck_cut` of the set: the exponential left out where it cannot count.
    stribeck_cut: f64,
}

impl<'a> Substep<'a> {
    /// Prepared for the many substeps of a simulation (the Stribeck cut computed: a logarithm).
    #[inline]
    pub fn new(p: &'a Params, load: &'a Load, law: FrictionLaw) -> Self {
        Self::with_cut(p, load, law, friction::stribeck_cut(p))
    }

    /// For a single substep or test (`step`, `rests_for_good`): no cut, so no logarithm for
    /// a substep it could save at most one exponential in; the numbers are the same (the cut
    /// is exact).
    #[inline]
    fn once(p: &'a Params, load: &'a Load, law: FrictionLaw) -> Self {
        Self::with_cut(p, load, law, f64::INFINITY)
    }

    #[inline]
    fn with_cut(p: &'a Params, load: &'a Load, law: FrictionLaw, stribeck_cut: f64) -> Self {
        Substep {
            p,
            load,
            law,
            inertia: p.motor_inertia + load.inertia,
            corrected: p.torque_gain != 1.0 || p.torque_bias != 0.0 || p.torque_drift != 0.0,
            spring: p.spring_stiffness != 0.0,
            plain: p.torque_gain == 1.0
                && p.torque_bias == 0.0
                && p.torque_drift == 0.0
                && p.spring_stiffness == 0.0
                && p.cogging_amplitude == 0.0
                && p.coulomb_asym == 0.0
                && p.friction_ripple_amplitude == 0.0
                && p.stribeck_torque == 0.0
                && p.load_coulomb == 0.0,
            stribeck_cut,
        }
    }

    /// `step`, given `gain` = h / `self.inertia` (computed once per sample interval by callers
    /// that take many equal substeps).
    #[inline(always)]
    pub fn advance(&self, state: &mut State, tau: f64, t: f64, gain: f64, h: f64) {
        let p = self.p;
        let omega = state.omega;
        let dissipation = p.damping + p.quadratic_drag * omega.abs();
        let (drive, level) = self.drive_and_level(state, tau, t);
        state.omega = friction::advance_with_gain(omega, gain, drive, dissipation, level, self.law, p.tanh_k);
        state.theta += h * state.omega;
    }

    /// The torque that does not depend on the velocity (`drive`) and the friction's level, at
    /// the start of a substep: `advance`'s, and `rests_for_good`'s test of the same numbers.
    #[inline(always)]
    fn drive_and_level(&self, state: &State, tau: f64, t: f64) -> (f64, f64) {
        let p = self.p;
        if self.plain {
            let gravity = self.load.gravity_torque * trig::sin(state.theta - p.angle_offset);
            return (tau - gravity, p.coulomb.max(0.0));
        }
        let tau_corrected = if self.corrected { p.torque_gain * tau - p.torque_bias - p.torque_drift * t } else { tau };
        let StaticTorques { gravity, cogging, .. } = angle_torques(p, self.load, state.theta, false);
        let mut drive = tau_corrected - gravity - cogging;
        if self.spring {
            drive -= p.spring_stiffness * (state.theta - p.spring_neutral);
        }
        (drive, friction::level_within(p, self.stribeck_cut, state.theta, state.omega, drive, gravity - tau_corrected))
    }
}

/// Whether a joint in `state` stays exactly where it is through every later substep, whatever
/// their lengths, while the applied torque stays `tau` and nothing depends on time
/// (`torque_drift` 0): the end of a drop, the joint held by stick friction. Why: a drop test
/// spends most of its record at rest, and the simulator can then fill the remaining samples
/// instead of stepping through them (`trial::simulate_into`), with the same numbers to the bit.
///
/// Exact, not approximate: at ω = 0 `step` computes the same drive and level every substep
/// (they depend on θ, ω and the torque alone), and `friction::advance_velocity` sets ω to 0
/// when |(h/I)·drive| ≤ (h/I)·level; |drive| ≤ level implies that for every h > 0, because a
/// rounded product is monotonic in its factor. Then θ + h·0 = θ. Only the stick law has such
/// a rest (tanh friction creeps), and only with a normal inertia (h/I finite).
pub fn rests_for_good(state: &State, p: &Params, load: &Load, law: FrictionLaw, tau: f64) -> bool {
    if law != FrictionLaw::Stick || state.omega != 0.0 || p.torque_drift != 0.0 {
        return false;
    }
    let substep = Substep::once(p, load, law);
    if !(substep.inertia.is_normal() && substep.inertia > 0.0) {
        return false;
    }
    let (drive, level) = substep.drive_and_level(state, tau, 0.0);
    drive.abs() <= level
}
