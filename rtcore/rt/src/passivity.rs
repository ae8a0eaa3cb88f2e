//! The passivity guard of one joint: an observer of the energy at the port between the hand
//! and the joint, and a damping the loop adds to the virtual model while the joint generates
//! energy beyond a margin (time-domain passivity control, admittance form).
//!
//! Why: the loop renders whatever virtual inertia the gate allows, and below the smallest
//! stable one (docs/fidelity.md: 0.063 of the servo's inertia on the MX-64 bench with
//! compensation) the horn oscillates under a gripping hand. A joint that oscillates feeds the
//! hand energy, so the energy balance sees it whatever caused it (Hannaford and Ryu, IEEE TRA
//! 2002: a passivity observer needs no model of the hand or the servo).
//!
//! The observer (each cycle, from what the loop measures and what the model holds):
//!
//! - `port`: the energy the hand has put into the joint, Σ τ̄·Δθ_horn over successive horn
//!   reads (τ̄ the mean of the hand torques the model took between them). A sum of position
//!   differences, not of a differentiated velocity: the encoder's quantization telescopes
//!   instead of accumulating.
//! - `stored`: ½·I·ω² of the virtual model at the last read, the energy a passive joint may
//!   give back.
//! - `balance`: the port's energy, with what the joint dissipated (the part of it beyond
//!   `stored`) and any deficit below 0 forgotten over `WINDOW_S`. A passive joint keeps it ≥ 0: it can give back only
//!   what the hand put in (the model says it dissipates B·ω² + F·|ω| ≥ 0 of it,
//!   `model_dissipated`); a joint that gives the hand more than it took has it < 0. The window is
//!   the usual remedy for an observer that banks a long passive stretch and lets the oscillation
//!   that follows run until the bank is spent (Ryu, Kwon and Hannaford, IEEE TRA 2004, discuss
//!   the same delay of a pure integral); what the model stores is kept, so a joint that coasted
//!   for a while may still give its energy back. The port's energy and not port − stored itself:
//!   a servo that follows late shows the port's energy late, and port − stored then dips below
//!   zero whenever the hand speeds the joint up (a false alarm on any uncompensated servo).
//!
//! The controller: while `balance < −ONSET_FRACTION·margin` (half the margin) and the joint is
//! still generating (the balance falling faster than margin / `WINDOW_S`, the power that would
//! hold it at the margin), a damping `damping` is added to the model. `passivity_margin` is the
//! most energy the joint may give the hand beyond what the hand put in (the windowed balance's
//! floor), not the point where the guard starts: it starts at half of it, and the other half is
//! the headroom for what still arrives once it acts (the horn follows goals already sent, and
//! the port's energy comes a tick's worth of motion at a time, τ·1.5 mrad: 0.5-0.8 mJ at the
//! torques of a gripping hand). Its target is the larger of two dampings, with E the energy
//! beyond the onset: Hannaford and Ryu's time-domain passivity law, E / (ω²·`DISSIPATE_S`) with
//! ω² the model's mean square velocity, the damping that takes E out of the model's motion
//! within `DISSIPATE_S` (their per-sample β = E/(h·v²) steps with every sample; spread over a few
//! wobble periods it does not); and I/`STOP_S` times E over the margin's other half, the damping
//! that brings the model to rest within `STOP_S`, reached as the balance reaches the margin and
//! growing beyond it. Why both: the first alone is tiny for a fast model (E of a few mJ against
//! ω² of tens), and a guard that started at the margin with it let the wall clock's stalls take
//! the joint 25-50 % past the margin (2 of 32 sessions, docs/fidelity.md); the second depends on
//! the joint's inertia, not its speed. The damping approaches the target with the time constant
//! `RISE_S` (5 ms; it never falls while the joint generates), is held `HOLD_S` after the joint
//! stopped generating (the observer cannot tell whether a joint the damping keeps quiet would
//! wobble again without it), then decays by e every `RELEASE_S` and is dropped below
//! `START_FRACTION`/10 of the maximum (a step far below a tick's worth of motion). It is applied
//! implicitly, ω ← ω / (1 + h·D/I), after the model's step: a velocity only ever brought
//! towards rest, stable for any D (an explicit D would need h·(B + D)/I < 1, which caps it too
//! low for the lightest inertias it is needed at), so the guard can only take energy out of the
//! model, never add it. This is the admittance form of the passivity controller (Hannaford and
//! Ryu 2002; Ryu, Kwon and Hannaford 2004: for a port of admittance causality, force in and
//! velocity out, the controller takes velocity away in proportion to the force; here through a
//! damper added to the model's own), which leaves the model's position continuous (Keemink, van
//! der Kooij and Stienen, IJRR 2018, on admittance control and the inertia beyond the sensor that
//! makes a light virtual joint oscillate). A guard that never acts leaves the cycle bit for bit
//! as a guard that is off: the observer only reads, and `damp` does nothing at zero damping
//! (dxlsim's lockstep tests check it on the simulated bench).
use crate::params::JointGains;
use plant::State;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// s: the observer's forgetting time (what the joint dissipated longer ago stops counting).
pub const WINDOW_S: f64 = 1.0;
/// s: the added damping approaches its target with this time constant while the joint generates
/// energy (fast: the old e-fold growth from 1/1000 of the maximum took 140 ms to matter).
pub const RISE_S: f64 = 0.005;
/// s: the target damping would take the energy beyond the margin out of the model's motion
/// within this time (Hannaford and Ryu's per-sample β = E/(h·v²), spread over this time instead
/// of one sample, so that neither the damping nor the goal steps).
pub const DISSIPATE_S: f64 = 0.05;
/// s: once the joint stops generating, the damping is held this long before it decays (the
/// observer cannot see whether a joint that the damping keeps quiet would wobble again without it;
/// releasing at once let the oscillation come back, a limit cycle of act and release).
pub const HOLD_S: f64 = 1.5;
/// s: then it decays by e this often.
pub const RELEASE_S: f64 = 0.5;
/// The added damping starts from at least this fraction of `passivity_damping_max`, and is
/// dropped once it has decayed below a tenth of it (a step far below a tick's worth of motion).
pub const START_FRACTION: f64 = 1e-3;
/// The guard starts acting once the balance has fallen below this fraction of −margin: the other
/// part of the margin is the headroom for what still arrives after it starts (the horn follows
/// goals already sent, and the port's energy comes in steps of a tick's worth of motion).
pub const ONSET_FRACTION: f64 = 0.5;
/// s: by the time the balance reaches the margin, the damping is at least the one that brings the
/// model's velocity to rest with this time constant (I/`STOP_S`), ramped in from the onset.
pub const STOP_S: f64 = 0.005;
/// s: the time constant of the generated power's low-pass (is the joint still generating?).
const POWER_S: f64 = 0.2;
/// s: the time constant of the model's mean square velocity (the target's v²): a few periods of
/// the wobble it is to damp.
const MOTION_S: f64 = 0.05;

/// A joint's guard settings (`passivity_guard`, `passivity_margin`, `passivity_damping_max`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassivityParams {
    /// 1 = on, 0 = off (turning it off lets an added damping decay, never drops it at once).
    pub guard: f64,
    /// J: the most energy the joint may give the hand beyond what the hand put in (the windowed
    /// balance's floor); the guard starts acting at `ONSET_FRACTION` of it.
    pub margin: f64,
    /// N·m·s/rad: the most damping the guard adds.
    pub damping_max: f64,
}

impl Default for PassivityParams {
    fn default() -> Self {
        PassivityParams { guard: 1.0, margin: 0.002, damping_max: 1.0 }
    }
}

/// The guard's state, in the loop thread.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PassivityGuard {
    params: PassivityParams,
    /// J: the hand's energy into the joint since the start.
    port: f64,
    /// J: what the model says it has dissipated since the start.
    model_dissipated: f64,
    /// J: ½·I·ω² of the model at the last horn read.
    stored: f64,
    /// J: the windowed balance the guard acts on (see the module doc).
    balance: f64,
    /// W, low-passed: how fast the balance falls (the joint's generated power).
    generating: f64,
    /// N·m·s/rad: the damping added now.
    damping: f64,
    /// rad²/s², low-passed: the model's mean square velocity.
    motion: f64,
    /// s: how much longer the damping is held before it decays.
    hold_left: f64,
    /// Episodes: the damping went from 0 to > 0.
    episodes: u64,
    /// The horn's angle at the last read, None until one after the last hold.
    horn: Option<f64>,
    /// Sum and count of the hand torques since that read.
    torque_sum: f64,
    torque_n: u32,
}

impl PassivityGuard {
    pub fn new(params: PassivityParams) -> Self {
        PassivityGuard { params, ..Default::default() }
    }

    /// A new parameter set: the damping added now stays and follows the new settings from here.
    pub fn retarget(&mut self, params: PassivityParams) {
        self.params = params;
    }

    /// One cycle of the observer and the controller, before the model's step: `horn` the angle
    /// of a horn read since the last cycle (None when there was none), `tau` the hand torque the
    /// model takes now, `model` its state and `gains` its gains. A `hold` (stale force, a fault,
    /// a recovery) breaks the port's record: the next read starts it again. Non-finite inputs
    /// are skipped (the state guard handles them); nothing here can panic.
    pub fn observe(&mut self, horn: Option<f64>, tau: f64, model: &State, gains: &JointGains, hold: bool, h: f64) {
        let before = self.balance;
        let stored = 0.5 * gains.inertia * model.omega * model.omega;
        if hold || !tau.is_finite() || !stored.is_finite() {
            self.horn = None;
            self.torque_sum = 0.0;
            self.torque_n = 0;
        } else {
            if let Some(theta) = horn.filter(|t| t.is_finite()) {
                // Both energies from one read to the next: with no read (none configured, a
                // silent servo) the port is not observed, and nothing is judged.
                if let (Some(last), true) = (self.horn, self.torque_n > 0) {
                    let work = self.torque_sum / self.torque_n as f64 * (theta - last);
                    self.port += work;
                    self.balance += work;
                }
                self.horn = Some(theta);
                self.stored = stored;
                self.torque_sum = 0.0;
                self.torque_n = 0;
            }
            self.torque_sum += tau;
            self.torque_n = self.torque_n.saturating_add(1);
            self.model_dissipated += (gains.damping * model.omega * model.omega + gains.coulomb * model.omega.abs()) * h;
        }
        self.motion += (model.omega * model.omega - self.motion) * h / (MOTION_S + h);
        let fallen = before - self.balance;
        self.generating += (fallen / h - self.generating) * h / (POWER_S + h);
        // Forget what the joint dissipated (the balance beyond what the model stores), not what
        // it holds: a joint the hand sped up may give that energy back however long it coasted.
        // A deficit is forgotten too, so that an episode ends once the joint stops generating.
        let forget = (self.balance - self.stored).max(0.0) + self.balance.min(0.0);
        self.balance -= forget * h / (WINDOW_S + h);
        if !(self.balance.is_finite() && self.generating.is_finite() && self.motion.is_finite()) {
            self.balance = 0.0; // a NaN would keep the guard from ever acting again
            self.generating = 0.0;
            self.motion = 0.0;
        }
        self.control(gains.inertia, h);
    }

    /// The damping's law (see the module doc).
    fn control(&mut self, inertia: f64, h: f64) {
        let p = self.params;
        let floor = p.damping_max * START_FRACTION;
        let onset = p.margin * ONSET_FRACTION;
        let excess = -(self.balance + onset);
        let on = p.guard > 0.0;
        // Still generating: faster than the power that holds the windowed balance at the margin
        // (a slower fall is the noise of the reads, and the window brings it back by itself).
        if on && excess > 0.0 && self.generating > p.margin / WINDOW_S {
            if self.damping == 0.0 {
                self.episodes += 1;
            }
            let target = self.target(excess, p.margin - onset, inertia);
            // Towards the target, never down while generating: no step, and what stopped the
            // generation stays.
            self.damping = (self.damping + (target - self.damping).max(0.0) * h / (RISE_S + h)).max(floor).min(p.damping_max);
            self.hold_left = HOLD_S;
        } else if on && (excess > 0.0 || self.hold_left > 0.0) && self.damping <= p.damping_max {
            self.hold_left = (self.hold_left - h).max(0.0);
        } else {
            self.hold_left = 0.0;
            self.damping *= (-h / RELEASE_S).exp();
            if self.damping < floor / 10.0 || !self.damping.is_finite() {
                self.damping = 0.0;
            }
        }
    }

    /// The damping aimed at, `excess` J beyond the onset with `headroom` J left to the margin: the
    /// larger of the TDPA law's and the one that stops the model within `STOP_S` by the margin
    /// (see the module doc). max/min, not clamp: the RT thread never panics on a NaN bound
    /// (f64::max and min take the other operand over a NaN).
    fn target(&self, excess: f64, headroom: f64, inertia: f64) -> f64 {
        let tdpa = excess / (self.motion.max(f64::MIN_POSITIVE) * DISSIPATE_S);
        let stop = excess / headroom.max(f64::MIN_POSITIVE) * inertia.max(0.0) / STOP_S;
        tdpa.max(stop).min(self.params.damping_max)
    }

    /// Applies the added damping to the model's state after its step (implicitly: the velocity
    /// is only brought towards rest); returns the acceleration it added, rad/s².
    pub fn damp(&self, state: &mut State, inertia: f64, h: f64) -> f64 {
        if self.damping <= 0.0 || inertia.is_nan() || inertia <= 0.0 {
            return 0.0;
        }
        let omega = state.omega / (1.0 + h * self.damping / inertia);
        let added = (omega - state.omega) / h;
        state.omega = omega;
        added
    }

    pub fn view(&self) -> PassivityView {
        PassivityView {
            balance: self.balance,
            port: self.port,
            model_dissipated: self.model_dissipated,
            damping: self.damping,
            episodes: self.episodes,
        }
    }
}

/// What the guard shows: the record's, the stats' and the monitor's figures.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PassivityView {
    /// J: the windowed balance (< −margin: the joint generated energy; the guard acts).
    pub balance: f64,
    /// J: the hand's energy into the joint since the start (negative: the joint gave energy).
    pub port: f64,
    /// J: what the virtual model dissipated since the start.
    pub model_dissipated: f64,
    /// N·m·s/rad: the damping added now (0: the guard is not acting).
    pub damping: f64,
    /// How many times the guard started acting.
    pub episodes: u64,
}

/// One joint's guard as the loop publishes it each cycle (relaxed stores of the view's bits).
#[derive(Default)]
pub struct PassivityShared {
    values: [AtomicU64; 5],
}

impl PassivityShared {
    pub fn publish(&self, v: &PassivityView) {
        let bits = [v.balance.to_bits(), v.port.to_bits(), v.model_dissipated.to_bits(), v.damping.to_bits(), v.episodes];
        for (slot, b) in self.values.iter().zip(bits) {
            slot.store(b, Relaxed);
        }
    }

    pub fn snapshot(&self) -> PassivityView {
        let f = |k: usize| f64::from_bits(self.values[k].load(Relaxed));
        PassivityView { balance: f(0), port: f(1), model_dissipated: f(2), damping: f(3), episodes: self.values[4].load(Relaxed) }
    }
}

#[cfg(test)]
#[path = "passivity_tests.rs"]
mod tests;
