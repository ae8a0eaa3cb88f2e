//! Servo compensation: the goal that makes the horn, not only the goal, follow the model.
//!
//! A position servo follows its goal late and gives way under the hand (`plant::servo`: a lag,
//! a second-order term, a dead time, a compliance and a friction band, identified from a
//! recording by `admittance fidelity`). The compensation sends, instead of the model's angle θ,
//! θ + w·lead, where `lead` is that model inverted a dead time ahead
//! (`plant::servo::lead`): it needs the model's own ω and acceleration, which the loop knows
//! exactly each cycle, and the hand's torque, which it measures. No numerical differentiation,
//! no knowledge of how the servo is built beyond what the recording showed.
//!
//! The model's acceleration enters the lead through the servo's inertial term (T·m·α): it is
//! what makes a second-order servo's horn keep up, and it is also the measured force divided by
//! the virtual inertia, so through a hand gripping the horn it feeds the hand's own inertial
//! torque back to the goal with a gain of T·m·I_hand/I_virtual at every frequency, cancelling
//! the servo's inertial roll-off: a light virtual joint then oscillates with the hand
//! (docs/fidelity.md, "smallest stable inertia"). So the acceleration is low-passed at twice the
//! servo's natural frequency 1/√(m·T), where the servo stops following anyway.
//!
//! **A virtual joint lighter than the servo.** The model's own terms give the servo's inertia:
//! for a position loop J·θ'' + K_d·θ' + K_p·(θ − u) = τ, T·m = J/K_p and s = 1/K_p, so
//! J = T·m/s (0.0146 kg·m² on the MX-64 bench, whose motor inertia is 0.01467). The inertial
//! term is then s·τ·J/I_v: it answers the hand's torque J/I_v times as hard as the servo's own
//! give, and a gripping hand's inertial torque closes that loop. Below I_v = J/2 the lead takes
//! only the share 2·I_v/J of the acceleration (`inertia_share`; the half is `LIGHT_BELOW`, a
//! margin for J's estimate), so that the term never answers the torque harder than it would at
//! I_v = J/2: a light joint's horn no longer follows the
//! model's acceleration in full, and a gripped one does not wobble with the loop's stalls
//! (measured: docs/fidelity.md, "The compensation's lead at light inertias"). At I_v ≥ J/2, and
//! for a model without a give or an inertial term, nothing changes.
//!
//! The friction term b·sgn ω is a relay on the model's velocity, smoothed over
//! `FRICTION_FADE_VELOCITY` (0.02 rad/s): near rest its gain is b/0.02 s, 6× the lag's T on the
//! MX-64 bench, and at a light virtual inertia the model's velocity at rest is the hand's
//! torque over a small inertia (0.07–0.14 rad/s RMS in the gripped sessions): the goal then
//! flips by ±b with it. The fade widens by the same share, 0.02/share rad/s, up to b/T, where
//! the gain at rest equals the lag term's T (`friction_fade`); a reference slower than that
//! keeps at most one deadband of error. At a share of 1 it is the plain 0.02.
//!
//! **Gear play.** A model with `backlash` adds the play's inverse (`plant::servo::PlaySide`):
//! the motor is sent to the side of the play the horn must be pushed from (behind the horn while
//! the hand leans on it, ahead of it while it drives a free horn), decided ahead on two horizons
//! (`play_horizons`: into a free horn only as early as the reference runs away from it, into a
//! held one as early as makes the error before and after the hand takes hold least, `held_lead`;
//! the hand's torque extrapolated from its rate, the model's speed from its acceleration) with
//! hystereses in the torque (one of them the torque's measured noise) and the speed so that the
//! force's noise does not make the goal chatter, and crossing it along a shaped path
//! driven by the servo's own inverse, in about the servo's natural time (`play_crossing`). It is
//! part of the lead (so of the watch's uncompensated prediction, the clip and the blend).
//!
//! w is a weight in [0, 1] (`servo_compensation`). It never jumps: a change blends linearly
//! over the loop's ramp time, but over at least `MIN_BLEND_S`, so that even with
//! `ramp_time_s = 0` turning the compensation on or off cannot step the goal by the whole lead.
//! While the force is stale (or a fault holds the joint) the loop holds, and the lead is frozen
//! with it, so the goal stays. The model then starts again from rest, where its lead is small:
//! the frozen lead's difference to the new one fades out over `RELEASE_S` instead of stepping
//! the goal back by it.
//!
//! **The watch.** A model that passed its fit can still be wrong for the servo it drives (a
//! different servo, a load, a form the fit could not see). So each read of the horn is compared:
//! the horn's error from the model's angle (what the hand feels), against the error the servo
//! model predicts *without* compensation, which is the lead itself (the lead is exactly how far
//! the model says the horn would trail). Both are mean squares over `WATCH_S`; once the weight
//! has been at its target for `2·WATCH_S`, an error above the uncompensated prediction (plus one
//! tick of quantisation) means the compensation makes the horn worse than none would: the weight
//! blends to 0 (the same blend as a live change: no jump) and `watch` says so once, for the
//! daemon's line. It stays off for that model and weight; a parameter set with another model or
//! weight tries again.
use crate::joint::bound;
use plant::servo::{lead_fading, PlaySide, ServoModel, FRICTION_FADE_VELOCITY};

/// The shortest blend of the weight, s.
pub const MIN_BLEND_S: f64 = 0.2;
/// A lead beyond this (rad) is clipped: a safety net against a wild model, far above any lag a
/// servo that follows at all shows (a 25 ms lag at 6 rad/s is 0.15 rad).
pub const MAX_LEAD: f64 = 0.3;
/// s: the time constant over which a frozen lead hands over to the running one after a hold.
pub const RELEASE_S: f64 = 0.05;
/// s: the window of the watch's mean squares (several periods of a hand's slowest motion).
pub const WATCH_S: f64 = 1.0;
/// The lead's acceleration share falls below 1 only for a virtual inertia under this fraction of
/// J = T·m/s (`inertia_share`): J is the fit's estimate (0.01499 kg·m² on the MX-64 bench against
/// its 0.01467), and a joint rendering about the servo's own inertia keeps its whole lead.
pub const LIGHT_BELOW: f64 = 0.5;

/// The running mean squares the watch compares (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Watch {
    /// Mean square of the horn's error from the model's angle, rad².
    error: f64,
    /// Mean square of the lead (the uncompensated prediction of that error), rad².
    lead: f64,
    /// s the weight has been at its (non-zero) target.
    settled: f64,
}

/// rad/s: the speed over which the lead's friction term b·sgn ω fades in, for a virtual joint
/// leading with `share` of its acceleration (`inertia_share`): `FRICTION_FADE_VELOCITY` divided
/// by the share, but never beyond b/T, the speed at which the servo's own lag error T·ω is one
/// deadband (see the module doc). At a share of 1 it is the plain `lead`'s.
fn friction_fade(model: &ServoModel, share: f64) -> f64 {
    (FRICTION_FADE_VELOCITY / share).min(model.deadband / model.time_constant).max(FRICTION_FADE_VELOCITY)
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Compensation {
    model: Option<ServoModel>,
    weight: f64,
    from: f64,
    to: f64,
    progress: f64,
    lead: f64,
    /// The acceleration the lead uses (low-passed, see the module doc).
    alpha: f64,
    /// The side of the gear play the horn rests on, and the goal offset for it.
    play: PlaySide,
    /// The last cycle held (the lead was frozen).
    held: bool,
    /// What is left of a frozen lead's difference to the running one (fades over RELEASE_S).
    carry: f64,
    watch: Watch,
    /// The (model, weight) the watch turned off: kept off until a set brings another.
    refused: Option<(Option<ServoModel>, f64)>,
    /// The virtual inertia rendered, kg·m² (`set_virtual_inertia`; infinite until set: the whole
    /// acceleration).
    inertia: f64,
}

impl Compensation {
    /// A joint's compensation at `weight` (already validated: 0 without a model).
    pub fn new(model: Option<ServoModel>, weight: f64) -> Self {
        Compensation {
            model,
            weight,
            from: weight,
            to: weight,
            progress: 1.0,
            lead: 0.0,
            alpha: 0.0,
            play: PlaySide::default(),
            held: false,
            carry: 0.0,
            watch: Watch::default(),
            refused: None,
            inertia: f64::INFINITY,
        }
    }

    /// The weight it blends to now.
    pub fn target(&self) -> f64 {
        self.to
    }

    /// The weight in use this cycle.
    pub fn weight(&self) -> f64 {
        self.weight
    }

    /// A new parameter set: blend from the weight in use to `weight`.
    pub fn retarget(&mut self, model: Option<ServoModel>, weight: f64) {
        if self.refused == Some((model, weight)) {
            return; // the watch turned this one off: the same set does not turn it on again
        }
        self.refused = None;
        self.model = model;
        self.blend_to(weight);
    }

    fn blend_to(&mut self, weight: f64) {
        if weight != self.to {
            self.watch = Watch::default();
            // A weight that bypassed the gate (NaN) is refused at the goal by the state guard;
            // the next blend starts from off, not from it.
            self.from = if self.weight.is_finite() { self.weight } else { 0.0 };
            self.to = weight;
            self.progress = 0.0;
        }
    }

    /// One read of the horn: `horn_error` = present angle − model angle (rad), `dt` s since the
    /// last read, `floor` the quantisation (rad, one tick). True once, when the compensation
    /// makes the horn worse than the uncompensated prediction and is turned off (blended out).
    pub fn watch(&mut self, horn_error: f64, dt: f64, floor: f64) -> bool {
        let settled = self.progress >= 1.0 && self.to > 0.0 && self.refused.is_none();
        if self.model.is_none() || !settled || self.held || !horn_error.is_finite() || !(dt > 0.0) {
            return false;
        }
        let share = dt / (WATCH_S + dt);
        let lead = self.lead + self.carry;
        self.watch.error += (horn_error * horn_error - self.watch.error) * share;
        self.watch.lead += (lead * lead - self.watch.lead) * share;
        self.watch.settled += dt;
        if self.watch.settled < 2.0 * WATCH_S || self.watch.error <= self.watch.lead + floor * floor {
            return false;
        }
        self.refused = Some((self.model, self.to));
        self.blend_to(0.0);
        true
    }

    /// Moves the blend on by one cycle of `h` seconds, over max(`ramp_time_s`, MIN_BLEND_S).
    pub fn advance(&mut self, h: f64, ramp_time_s: f64) {
        if self.progress >= 1.0 {
            return;
        }
        self.progress = (self.progress + h / ramp_time_s.max(MIN_BLEND_S)).min(1.0);
        self.weight = self.from + self.progress * (self.to - self.from);
    }

    /// A cycle whose goal was not made here (a fault held the joint): the lead stays frozen,
    /// and the next goal hands it over as after any hold.
    pub fn hold(&mut self) {
        self.held = true;
    }

    /// The model was moved to where the horn is (a recovered servo): no lead to carry over,
    /// and the next running cycle starts its lead from nothing, as after any hold.
    pub fn reanchor(&mut self) {
        self.lead = 0.0;
        self.carry = 0.0;
        self.alpha = 0.0;
        self.play = PlaySide::default();
        self.held = true;
    }

    /// The virtual inertia the model renders now (kg·m²), for the lead's acceleration share.
    pub fn set_virtual_inertia(&mut self, inertia: f64) {
        self.inertia = inertia;
    }

    /// The share of the model's acceleration the lead uses: min(1, I_v / (LIGHT_BELOW·J)), J = T·m/s
    /// the servo's own inertia as its model implies it (see the module doc). 1 when the model
    /// implies none (no compliance or no inertial term) or the inertia is not a positive number.
    fn inertia_share(&self, model: &ServoModel) -> f64 {
        let own = LIGHT_BELOW * model.time_constant * model.inertial_time / model.compliance;
        let share = self.inertia / own;
        if own.is_finite() && own > 0.0 && share.is_finite() && share > 0.0 { share.min(1.0) } else { 1.0 }
    }

    /// The angle to send as the goal for a model at `theta` moving at `omega` with
    /// acceleration `alpha` under the hand torque `tau`. With `hold` (stale force) the lead of
    /// the last cycle is kept, so holding never moves the goal.
    /// `h` is the cycle's step (for the acceleration's filter).
    pub fn goal(&mut self, theta: f64, omega: f64, alpha: f64, tau: f64, hold: bool, h: f64) -> f64 {
        let Some(model) = self.model else { return theta };
        // A non-finite input would stay in the filter for good: the lead is then kept as it was.
        if !hold && alpha.is_finite() && tau.is_finite() {
            let corner = 2.0 / (model.inertial_time * model.time_constant).sqrt(); // rad/s
            let share = if corner.is_finite() { h * corner / (1.0 + h * corner) } else { 1.0 }; // m = 0: no filter
            self.alpha += (alpha - self.alpha) * share;
            let play = self.play.update(&model, omega, self.alpha, tau, h);
            let share = self.inertia_share(&model);
            let led = lead_fading(&model, omega, self.alpha * share, tau, friction_fade(&model, share)) + play;
            // Finite inputs and a validated model give a finite lead; a NaN would still reach the
            // goal tick as tick 0 (a jump across the range), so it is refused here too.
            let led = if led.is_finite() { bound(led, MAX_LEAD) } else { self.lead };
            if self.held {
                self.carry += self.lead - led; // released: hand the frozen lead over, no step
            }
            self.carry -= self.carry * h / (RELEASE_S + h);
            self.lead = led;
        }
        self.held = hold;
        theta + self.weight * (self.lead + self.carry)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAG: ServoModel =
        ServoModel { dead_time: 0.002, compliance: 0.01, ..ServoModel::first_order_lag(0.025) };

    #[test]
    fn without_a_model_the_goal_is_the_model_angle() {
        let mut c = Compensation::new(None, 0.0);
        assert_eq!(c.goal(0.3, 2.0, 5.0, 0.4, false, 1e-3), 0.3);
    }

    #[test]
    fn the_lead_is_the_inverted_servo_model_weighted_and_clipped() {
        let mut c = Compensation::new(Some(LAG), 1.0);
        let g = c.goal(0.1, 1.0, 0.0, 0.5, false, 1e-3);
        assert!((g - (0.1 + 0.025 + 0.002 - 0.005)).abs() < 1e-12, "{g}");
        assert_eq!(c.goal(0.1, 100.0, 0.0, 0.0, false, 1e-3), 0.1 + MAX_LEAD);
    }

    #[test]
    fn turning_it_on_blends_over_at_least_the_minimum_time() {
        let mut c = Compensation::new(Some(LAG), 0.0);
        c.retarget(Some(LAG), 1.0);
        let h = 1e-3;
        let mut last = c.goal(0.0, 1.0, 0.0, 0.0, false, h);
        for _ in 0..(MIN_BLEND_S / h) as usize + 5 {
            c.advance(h, 0.0);
            let g = c.goal(0.0, 1.0, 0.0, 0.0, false, h);
            assert!(g - last <= 0.027 * h / MIN_BLEND_S + 1e-12, "a step of {}", g - last);
            last = g;
        }
        assert_eq!(c.weight(), 1.0);
    }

    #[test]
    fn a_release_hands_the_frozen_lead_over_without_a_step() {
        let mut c = Compensation::new(Some(LAG), 1.0);
        let h = 1e-3;
        let moving = c.goal(0.2, 1.0, 0.0, 0.0, false, h);
        assert_eq!(c.goal(0.2, 0.0, 0.0, 0.0, true, h), moving);
        let released = c.goal(0.2, 0.0, 0.0, 0.0, false, h);
        assert!((released - moving).abs() < 0.027 * h / RELEASE_S * 1.01, "{released} after {moving}");
        for _ in 0..(10.0 * RELEASE_S / h) as usize {
            c.goal(0.2, 0.0, 0.0, 0.0, false, h);
        }
        assert!((c.goal(0.2, 0.0, 0.0, 0.0, false, h) - 0.2).abs() < 1e-5, "the running lead (0 at rest) in the end");
    }

    #[test]
    fn a_non_finite_input_never_poisons_the_lead() {
        let model = ServoModel { inertial_time: 0.02, ..LAG }; // with the acceleration filter
        let mut c = Compensation::new(Some(model), 1.0);
        let before = c.goal(0.1, 1.0, 2.0, 0.1, false, 1e-3);
        assert_eq!(c.goal(0.1, 1.0, f64::NAN, 0.1, false, 1e-3), before, "the lead kept");
        assert_eq!(c.goal(0.1, 1.0, 2.0, f64::INFINITY, false, 1e-3), before);
        let faster = c.goal(0.1, 2.0, 2.0, 0.1, false, 1e-3);
        assert!(faster.is_finite() && faster > before + 0.01, "and the next cycles lead again: {faster}");
    }

    /// Drives `c` at a steady sine for `seconds`, with the horn `error(lead)` off the model;
    /// returns the cycle (if any) the watch turned it off, and the largest goal step.
    fn watched(c: &mut Compensation, seconds: f64, error: impl Fn(f64) -> f64) -> (Option<usize>, f64) {
        let h = 1e-3;
        let (mut fell, mut last, mut step): (Option<usize>, Option<f64>, f64) = (None, None, 0.0);
        for k in 0..(seconds / h) as usize {
            let t = k as f64 * h;
            let (theta, omega) = (0.2 * (6.0 * t).sin(), 1.2 * (6.0 * t).cos());
            c.advance(h, 0.0);
            let goal = c.goal(theta, omega, 0.0, 0.0, false, h);
            if let Some(g) = last {
                step = step.max((goal - theta - g).abs());
            }
            last = Some(goal - theta);
            if k % 2 == 0 && c.watch(error(goal - theta), 2.0 * h, 1.5e-3) && fell.is_none() {
                fell = Some(k);
            }
        }
        (fell, step)
    }

    #[test]
    fn the_watch_keeps_a_compensation_that_helps() {
        let mut c = Compensation::new(Some(LAG), 1.0);
        // The horn within a tick of the model: what a good model gives.
        let (fell, _) = watched(&mut c, 5.0, |_| 1e-3);
        assert_eq!(fell, None);
        assert_eq!(c.weight(), 1.0);
    }

    #[test]
    fn the_watch_blends_out_a_compensation_that_makes_the_horn_worse_and_keeps_it_off() {
        let mut c = Compensation::new(Some(LAG), 1.0);
        // The horn overshoots the model by twice the lead: worse than trailing by it.
        let (fell, step) = watched(&mut c, 5.0, |lead| 2.0 * lead);
        let k = fell.expect("the watch turns it off");
        assert!(k as f64 * 1e-3 >= 2.0 * WATCH_S - 2e-3, "not before 2·WATCH_S at full weight: cycle {k}");
        assert_eq!(c.weight(), 0.0, "blended out");
        assert!(step < 1e-3, "no jump (the whole lead is ~30 mrad): a step of {step}");
        c.retarget(Some(LAG), 1.0);
        assert_eq!(c.target(), 0.0, "the same set does not turn it on again");
        c.retarget(Some(LAG), 0.5);
        assert_eq!(c.target(), 0.5, "another weight tries again");
    }

    #[test]
    fn a_geared_model_crosses_the_play_when_the_hand_reverses_without_a_step() {
        let geared = ServoModel { backlash: 0.01, backlash_torque: 0.02, ..LAG };
        let mut c = Compensation::new(Some(geared), 1.0);
        let h = 1e-3;
        let pushed = c.goal(0.0, 0.0, 0.0, 0.1, false, h);
        for _ in 0..400 {
            c.goal(0.0, 0.0, 0.0, 0.1, false, h);
        }
        let behind = c.goal(0.0, 0.0, 0.0, 0.1, false, h);
        assert!((behind - (-0.005 - 0.001)).abs() < 1e-9, "half the play behind the horn, less the give: {behind}");
        assert!(pushed > behind, "crossing, not stepping: {pushed}");
        let mut last = behind;
        for _ in 0..400 {
            let g = c.goal(0.0, 0.0, 0.0, -0.1, false, h);
            // The give (0.002) steps with the hand's torque; the play's crossing by less than the play.
            assert!((g - last).abs() <= 0.01 + 0.002 + 1e-12, "a step of {}", g - last);
            last = g;
        }
        assert!((last - (0.005 + 0.001)).abs() < 1e-9, "the hand reversed: the other side: {last}");
        c.reanchor();
        assert_eq!(c.goal(0.0, 0.0, 0.0, 0.0, false, h), 0.0, "a re-anchor forgets the side");
    }

    #[test]
    fn holding_freezes_the_lead() {
        let mut c = Compensation::new(Some(LAG), 1.0);
        let moving = c.goal(0.2, 1.0, 0.0, 0.3, false, 1e-3);
        assert_eq!(c.goal(0.2, 0.0, 0.0, 0.0, true, 1e-3), moving);
    }

    /// The MX-64 bench's servo model as `fidelity` identifies it under a gripping hand.
    const MX: ServoModel = ServoModel {
        time_constant: 0.017,
        inertial_time: 0.0213,
        dead_time: 0.0,
        compliance: 0.0248,
        deadband: 0.00206,
        backlash: 0.0,
        backlash_torque: 0.0,
    };

    /// The lead's acceleration part: the goal for `alpha` less the goal for none, settled
    /// through the acceleration's filter (the model moving at 1 rad/s, no torque).
    fn inertial_lead(c: &mut Compensation, alpha: f64) -> f64 {
        let h = 1e-3;
        for _ in 0..2000 {
            c.goal(0.0, 1.0, alpha, 0.0, false, h);
        }
        let with = c.goal(0.0, 1.0, alpha, 0.0, false, h);
        for _ in 0..2000 {
            c.goal(0.0, 1.0, 0.0, 0.0, false, h);
        }
        with - c.goal(0.0, 1.0, 0.0, 0.0, false, h)
    }

    #[test]
    fn a_virtual_joint_lighter_than_the_servo_leads_with_its_share_of_the_acceleration() {
        // J = T·m/s = 0.0146 kg·m², the servo's own inertia as its model implies it.
        let own = MX.time_constant * MX.inertial_time / MX.compliance;
        let full = MX.time_constant * MX.inertial_time * 10.0;
        let mut c = Compensation::new(Some(MX), 1.0);
        assert!((inertial_lead(&mut c, 10.0) - full).abs() < 1e-9, "not set: the whole acceleration");
        for (inertia, share) in [(own, 1.0), (own / 2.0, 1.0), (4.0 * own, 1.0), (own / 4.0, 0.5), (own / 64.0, 1.0 / 32.0)] {
            c.set_virtual_inertia(inertia);
            let led = inertial_lead(&mut c, 10.0);
            assert!((led - share * full).abs() < 1e-9 * full, "I = {inertia}: {led} against {}", share * full);
        }
        // Nothing the loop could hand it makes the goal non-finite or drops the lead.
        for inertia in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            c.set_virtual_inertia(inertia);
            assert!((inertial_lead(&mut c, 10.0) - full).abs() < 1e-9, "I = {inertia}: the whole acceleration");
        }
        // A model that implies no inertia of its own (no give to the hand) keeps the whole term.
        let stiff = ServoModel { compliance: 0.0, ..MX };
        let mut c = Compensation::new(Some(stiff), 1.0);
        c.set_virtual_inertia(own / 16.0);
        assert!((inertial_lead(&mut c, 10.0) - full).abs() < 1e-9);
    }

    #[test]
    fn at_a_light_virtual_inertia_the_friction_term_gains_no_more_near_rest_than_the_lag_term() {
        // There the model's velocity at rest is the hand's torque over a small inertia: the
        // friction term b·sgn ω must not turn it into a goal flipping by ±b.
        let own = MX.time_constant * MX.inertial_time / MX.compliance;
        let h = 1e-3;
        let at = |c: &mut Compensation, omega: f64| c.goal(0.0, omega, 0.0, 0.0, false, h);
        let slope = |c: &mut Compensation, omega: f64| (at(c, omega) - at(c, -omega)) / (2.0 * omega);
        let mut c = Compensation::new(Some(MX), 1.0);
        c.set_virtual_inertia(own / 64.0);
        for omega in [1e-4, 0.01, 0.05] {
            let gain = slope(&mut c, omega);
            assert!(gain <= 2.0 * MX.time_constant + 1e-12, "ω = {omega}: a gain of {gain} s");
        }
        // Well beyond b/T the whole deadband is compensated.
        let fast = at(&mut c, 2.0);
        assert!((fast - (MX.time_constant * 2.0 + MX.deadband)).abs() < 0.01 * MX.deadband, "{fast}");
        // At I_v ≥ J, the plain lead's fade (0.02 rad/s): b/0.02 + T near rest.
        c.set_virtual_inertia(own);
        let gain = slope(&mut c, 1e-4);
        let plain = MX.deadband / FRICTION_FADE_VELOCITY + MX.time_constant;
        assert!((gain - plain).abs() < 1e-3 * plain, "{gain} against {plain}");
    }
}
