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
use plant::servo::{lead, PlaySide, ServoModel};

/// The shortest blend of the weight, s.
pub const MIN_BLEND_S: f64 = 0.2;
/// A lead beyond this (rad) is clipped: a safety net against a wild model, far above any lag a
/// servo that follows at all shows (a 25 ms lag at 6 rad/s is 0.15 rad).
pub const MAX_LEAD: f64 = 0.3;
/// s: the time constant over which a frozen lead hands over to the running one after a hold.
pub const RELEASE_S: f64 = 0.05;
/// s: the window of the watch's mean squares (several periods of a hand's slowest motion).
pub const WATCH_S: f64 = 1.0;

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
            let led = lead(&model, omega, self.alpha, tau) + play;
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
}
