//! The servo's tracking dynamics: how a position servo's horn follows the goal it is sent.
//!
//! The admittance loop commands a goal; the horn gets there late, by the servo's own position
//! loop, and gives way under the hand. One model serves both ways it is used: the fidelity fit
//! simulates it (goal and hand torque in, horn angle out) and the RT loop inverts it (the goal
//! that makes the horn follow the admittance model). Both call this file, so the physics the
//! compensation assumes is exactly the physics that was fitted.
//!
//! The model, with θ the horn angle, u the goal and τ the hand torque:
//!
//! ```text
//!     m·θ'' + θ' = (u(t − d) + s·τ(t) − θ − b·sgn θ') / T
//! ```
//!
//! - `time_constant` T (s): the lag. A servo following a ramp at v rad/s runs T·v behind.
//! - `inertial_time` m (s): the second-order part (the horn's inertia over its damping); 0 is a
//!   plain first-order lag, θ' = (u − θ)/T.
//! - `dead_time` d (s): the goal acts this late (bus, firmware period, the reads' timing).
//! - `compliance` s (rad/N·m): how far the hand's torque pushes the horn off its goal at rest.
//! - `deadband` b (rad): the horn sticks while its effective error is within ±b (friction
//!   against the position loop's stiffness), with the plant's exact stick law.
//!
//! Why this form: a P-controlled DC servo (BAM's MX model: duty ∝ error, capped; torque
//! kt/R·V − kt²/R·ω; horn inertia I, viscous B, Coulomb F) is, below its duty cap,
//! I·θ'' + (B + kt²/R)·θ' = K·(u − θ) + τ − F·sgn θ' with K the loop's stiffness. Divided by the
//! total damping D = B + kt²/R it is the equation above with T = D/K, m = I/D, s = 1/K and
//! b = F/K. A servo whose horn simply lags its goal (no inertia, no give) is the same equation
//! with m = s = b = 0. Every term is in radians inside the bracket, so the parameters read as
//! times and angles whatever the motor.
//!
//! **Gear backlash.** A geared servo (every geared Dynamixel: the MX datasheets give a few tenths
//! of a degree) has play between its motor and its horn. The equation above is then the motor's
//! (in horn radians), and the horn sits within ±`backlash`/2 of it: a hand that pushes harder
//! than `backlash_torque` (the horn's own friction) holds it against the side it pushes to;
//! below that the horn stays where it is until the motor's side of the play drags it (a play
//! operator, `horn_in_play`). With `backlash` = 0 the horn is the motor, exactly.
//!
//! The velocity update is the plant's stick-slip step (`friction::advance_velocity`) multiplied
//! through by m, so that m = 0 is exact instead of a division by zero.
use rayon::prelude::*;

use crate::error::{require_finite, PlantError};
use crate::model::State;
use crate::trial::{validate_max_step, walk, TorqueCursor, Walk};

/// Number of servo-model parameters.
pub const N_SERVO_PARAMS: usize = 7;

/// Servo-model parameter names in vector order (the `[servo]` table of a parameter file).
pub const SERVO_PARAM_NAMES: [&str; N_SERVO_PARAMS] =
    ["time_constant", "inertial_time", "dead_time", "compliance", "deadband", "backlash", "backlash_torque"];

/// What a `[servo]` table without a key means: `None` = required; the backlash's two keys came
/// later and default to 0 (no play), so a table written before them loads unchanged.
pub const SERVO_PARAM_DEFAULTS: [Option<f64>; N_SERVO_PARAMS] = [None, None, None, None, None, Some(0.0), Some(0.0)];

/// N·m: a force sensor's torque noise. The compensation takes a hand torque for a push across the
/// play only beyond max(`backlash_torque`, this), and extrapolates the torque only beyond this,
/// so a fitted horn friction below the noise does not make the goal chatter across the play at
/// rest.
pub const PLAY_TORQUE_MIN: f64 = 0.01;
/// rad/s: below this model speed the compensation does not take the direction of travel for
/// the side the motor must push from (the model's velocity at rest is the force's noise / B).
pub const PLAY_VELOCITY_MIN: f64 = 0.02;
/// s: the window over which the compensation measures the hand torque's noise (the mean square
/// of its second differences): long against a crossing of the play (tens of ms), so the hand's
/// own pushes do not count, short against a session.
pub const PLAY_NOISE_WINDOW: f64 = 1.0;

/// Below this speed (rad/s) the compensation's friction term fades to zero (a smooth sign), so
/// a reference that starts or reverses does not step the goal.
pub const FRICTION_FADE_VELOCITY: f64 = 0.02;

/// Each parameter's physical domain, in `SERVO_PARAM_NAMES` order: what a Dynamixel's position
/// loop can be (a lag up to 1 s, a horn that gives at most 0.5 rad per N·m, a deadband up to
/// 0.05 rad, about 3°, a play up to 0.035 rad, 2°, ten times the MX datasheets', moved by a hand
/// torque of at most 2 N·m). The fidelity fit searches inside it, and `validate` refuses anything
/// outside, so an absurd `[servo]` table (a compliance of 1e300) never reaches the loop. A
/// slightly negative dead time is allowed because a recording labels the goal and the present
/// position with the same cycle time, while the read happens after the write.
pub const SERVO_DOMAIN: [(f64, f64); N_SERVO_PARAMS] = [(0.0, 1.0), (0.0, 0.5), (-0.02, 0.2), (-0.5, 0.5), (0.0, 0.05), (0.0, 0.035), (0.0, 2.0)];

/// A servo's tracking dynamics (see the module documentation for the equation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoModel {
    /// T, s (> 0).
    pub time_constant: f64,
    /// m, s (≥ 0; 0 = first-order lag).
    pub inertial_time: f64,
    /// d, s.
    pub dead_time: f64,
    /// s, rad/(N·m).
    pub compliance: f64,
    /// b, rad (≥ 0).
    pub deadband: f64,
    /// The play between motor and horn, rad (≥ 0; 0 = no gear play).
    pub backlash: f64,
    /// The hand torque that holds the horn against a side of the play, N·m (≥ 0).
    pub backlash_torque: f64,
}

impl ServoModel {
    /// A plain first-order lag with time constant `t` (no inertia, delay, give or friction).
    pub const fn first_order_lag(t: f64) -> ServoModel {
        ServoModel {
            time_constant: t,
            inertial_time: 0.0,
            dead_time: 0.0,
            compliance: 0.0,
            deadband: 0.0,
            backlash: 0.0,
            backlash_torque: 0.0,
        }
    }

    /// The model from a vector in `SERVO_PARAM_NAMES` order (validated).
    pub fn from_slice(values: &[f64]) -> Result<ServoModel, PlantError> {
        let v: [f64; N_SERVO_PARAMS] = values.try_into().map_err(|_| {
            PlantError::Shape(format!("a servo model has {N_SERVO_PARAMS} values, got {}", values.len()))
        })?;
        let model = ServoModel {
            time_constant: v[0],
            inertial_time: v[1],
            dead_time: v[2],
            compliance: v[3],
            deadband: v[4],
            backlash: v[5],
            backlash_torque: v[6],
        };
        model.validate()?;
        Ok(model)
    }

    pub fn to_array(&self) -> [f64; N_SERVO_PARAMS] {
        [
            self.time_constant,
            self.inertial_time,
            self.dead_time,
            self.compliance,
            self.deadband,
            self.backlash,
            self.backlash_torque,
        ]
    }

    /// `Ok(())` when every value is finite and within its domain; the error names the value.
    pub fn validate(&self) -> Result<(), PlantError> {
        for (name, value) in SERVO_PARAM_NAMES.iter().zip(self.to_array()) {
            require_finite(name, value)?;
        }
        for ((name, value), (lo, hi)) in SERVO_PARAM_NAMES.iter().zip(self.to_array()).zip(SERVO_DOMAIN) {
            // time_constant's domain is open at 0 (it divides).
            let inside = if *name == "time_constant" { value > lo && value <= hi } else { (lo..=hi).contains(&value) };
            if !inside {
                return Err(PlantError::InvalidValue(format!("{name} must be within [{lo}, {hi}], got {value}")));
            }
        }
        Ok(())
    }
}

/// The velocity after one substep of m·ω' = (e − b·sgn ω)/T − ω, implicit in the damping and in
/// the stiffness (e⁺ = e − h·ω⁺) so that no (m, T) makes it diverge, not even a lag far below the
/// substep that an optimiser may probe: (m + h + h²/T)·ω⁺ = m·ω + h·(e ∓ b)/T. The friction is the
/// plant's stick law: the horn stops exactly when |m·ω + h·e/T| ≤ h·b/T. For m = 0 this is the
/// implicit Euler step of the first-order lag.
#[inline]
fn advance(omega: f64, model: &ServoModel, error: f64, h: f64) -> f64 {
    let inv_t = 1.0 / model.time_constant;
    let free = model.inertial_time * omega + h * error * inv_t;
    let level = h * model.deadband * inv_t;
    if free.abs() <= level {
        return 0.0;
    }
    (free - free.signum() * level) / (model.inertial_time + h + h * h * inv_t)
}

/// Advances the horn by one substep of length `h` under the goal it sees now (`goal`, already
/// delayed by the caller) and the hand torque `tau`. Expects a validated model and h > 0.
#[inline]
pub fn step(state: &mut State, model: &ServoModel, goal: f64, tau: f64, h: f64) {
    let error = goal + model.compliance * tau - state.theta;
    state.omega = advance(state.omega, model, error, h);
    state.theta += h * state.omega;
}

/// The goal offset that makes a horn with this model follow a reference moving at `omega`
/// rad/s with acceleration `alpha` under the hand torque `tau`: the model inverted, a dead time
/// ahead. The goal is then reference + lead.
///
/// From the equation with θ = the reference: u(t − d) = θ + T·(m·θ'' + θ') + b·sgn θ' − s·τ at
/// t. Over the dead time the reference is extrapolated at constant acceleration and the torque
/// held, so everything needed is the reference's own state: no numerical differentiation.
#[inline]
pub fn lead(model: &ServoModel, omega: f64, alpha: f64, tau: f64) -> f64 {
    lead_fading(model, omega, alpha, tau, FRICTION_FADE_VELOCITY)
}

/// `lead` with its friction term fading in over `fade_velocity` rad/s instead of
/// `FRICTION_FADE_VELOCITY` (the RT loop's compensation widens it at light virtual inertias).
#[inline]
pub fn lead_fading(model: &ServoModel, omega: f64, alpha: f64, tau: f64, fade_velocity: f64) -> f64 {
    let d = model.dead_time;
    let omega_ahead = omega + alpha * d;
    let travel = omega * d + 0.5 * alpha * d * d;
    let lag = model.time_constant * (model.inertial_time * alpha + omega_ahead);
    let fade = omega_ahead / (omega_ahead * omega_ahead + fade_velocity * fade_velocity).sqrt();
    travel + lag + model.deadband * fade - model.compliance * tau
}

/// Where the play leaves the horn (at `horn` before) once the motor side is at `motor` (horn
/// radians) under the hand torque `tau`: held against the side the hand pushes to when it pushes
/// harder than `backlash_torque`, otherwise where it was, dragged by whichever side of the play
/// reaches it. With no backlash, the motor.
#[inline]
pub fn horn_in_play(model: &ServoModel, horn: f64, motor: f64, tau: f64) -> f64 {
    let half = 0.5 * model.backlash;
    if tau.abs() > model.backlash_torque {
        motor + half * tau.signum()
    } else {
        horn.max(motor - half).min(motor + half)
    }
}

/// s: the play's crossing time for this servo, the mean delay of the shaped crossing (see
/// `PlaySide`): the servo's own time scale, its natural period 1/ω_n = √(m·T), but not below its
/// lag T (so that the drive term T·v stays within a few β: T/crossing ≤ 1, m·T/crossing² ≤ 1).
pub fn play_crossing(model: &ServoModel) -> f64 {
    (model.inertial_time * model.time_constant).sqrt().max(model.time_constant)
}

/// s: the base of how far ahead the side of the play is decided: the goal acts a dead time late,
/// and a shaped crossing is centred on the moment the horn changes sides when it starts half its
/// mean delay before it. The two horizons the side is decided on (`play_horizons`) are this with
/// the crossing's share shifted by what the reference does meanwhile; the hand's torque rate is
/// smoothed over half of it (`PlaySide`).
pub fn play_ahead(model: &ServoModel) -> f64 {
    model.dead_time.max(0.0) + 0.5 * play_crossing(model)
}

/// The share of a shaped crossing (`PlaySide`: three first-order stages) still to go `u` stage
/// times after it started: the survival of the three stages' Erlang delay, e^(−u)·(1 + u + u²/2).
pub fn crossing_left(u: f64) -> f64 {
    (-u).exp() * (1.0 + u + 0.5 * u * u)
}

/// Stage times: how long before the hand takes hold of a free horn the crossing should start, for
/// a reference that travels a share `r` of the play per stage time (r = |ω|·stage/β).
///
/// Started u stage times early, the motor leaves the free horn standing for those u (the horn
/// falls behind at the reference's speed: an error r·s·β after s of them), and when the hand takes
/// hold the horn jumps to the motor, still `crossing_left(u)`·β from its side. The squared error,
/// r²·u³/3 before plus ∫ from u of crossing_left² after (in β²·stage), is least where its two
/// rates meet: crossing_left(u) = r·u (a unique root: the left falls, the right rises). Found by
/// bisection in a fixed number of steps (RT: no loop that depends on the data), within 0–40
/// stage times whatever r (a non-positive r gives 40, a NaN one 0).
pub fn held_lead(r: f64) -> f64 {
    let (mut low, mut high) = (0.0, 40.0);
    for _ in 0..48 {
        let mid = 0.5 * (low + high);
        if crossing_left(mid) > r * mid {
            low = mid;
        } else {
            high = mid;
        }
    }
    0.5 * (low + high)
}

/// s: the two horizons the side of the play is decided on, for a reference moving at `omega`
/// (rad/s, a dead time ahead): (into a free horn, into a held horn).
///
/// The two ways the horn changes sides do not cost the same. While the hand pushes beyond the
/// horn's friction it *holds* the horn against the motor: every bit of the motor's offset shows in
/// the horn, one to one. Within the friction the horn is *free*: it stands where it is until the
/// motor's side of the play reaches it, so it falls behind the reference only at the reference's
/// own speed. So a crossing into a free horn (the hand lets go: the direction-of-travel rule) is
/// started only as early as the reference would run away from it: half the crossing times
/// x = min(1, |ω|·crossing / (β/2)), the share of half the play the reference travels in one
/// crossing (at rest: on the moment itself, no pushing the horn ahead of a reference that does not
/// come). A crossing into a held horn (the hand takes hold) is started so that the error it leaves
/// is least (`held_lead`): the free horn left early falls behind at the reference's speed, the
/// share of the crossing not done when the hand takes hold shows whole; the reference's speed
/// taken at least `PLAY_VELOCITY_MIN` (slower is the noise's: at rest the crossing is then about
/// done, a few stage times early, instead of running on). That balance takes the horn free
/// before the hand takes hold; a hand that reverses through the friction's band in less than a
/// crossing holds it the other way until then, and the horn follows the motor one to one: there
/// the held horizon stays no shorter than before, (2 − x)·crossing/2 (the crossing centred on
/// the switch, `play_ahead`, for a fast reference). Both add the dead time ahead (a positive one:
/// the goal acts that late).
pub fn play_horizons(model: &ServoModel, omega: f64) -> (f64, f64) {
    let crossing = play_crossing(model);
    let share = (2.0 * omega.abs() * crossing / model.backlash).min(1.0); // a NaN ω gives 1 (min)
    let dead = model.dead_time.max(0.0);
    let stage = crossing / 3.0;
    let runaway = omega.abs().max(PLAY_VELOCITY_MIN) * stage / model.backlash; // a NaN ω: the floor
    let through = dead + 0.5 * crossing * (2.0 - share);
    (dead + 0.5 * crossing * share, (dead + stage * held_lead(runaway)).max(through))
}

/// The held torque's noise (`PlaySide`), as a multiple of a white torque noise's variance: the
/// prediction τ̄₀·(1 + c) − c·τ̄₁ (τ̄₀ the torque through a first-order low-pass of step share
/// `share`, τ̄₁ that through it again, c = (held horizon + its time constant) / its time
/// constant) is a linear filter of the torque, whose variance for white noise is the sum of its
/// impulse response squared: with x = (1 − share)², Σ τ̄₀² = share²/(1 − x),
/// Σ τ̄₁² = share⁴·(1 + x)/(1 − x)³, Σ τ̄₀·τ̄₁ = share³/(1 − x)².
pub fn held_torque_noise(share: f64, c: f64) -> f64 {
    let x = (1.0 - share) * (1.0 - share);
    let (zero, one, both) = (share * share / (1.0 - x), share.powi(4) * (1.0 + x) / (1.0 - x).powi(3), share.powi(3) / (1.0 - x).powi(2));
    (1.0 + c) * (1.0 + c) * zero - 2.0 * c * (1.0 + c) * both + c * c * one
}

/// The compensation's inverse of the play: which side of it the horn rests on (−1, 0, +1; the
/// horn at motor + side·backlash/2), decided each cycle from what the loop knows, and the goal
/// offset that takes the motor there, −side·backlash/2, along a shaped crossing.
///
/// **The side** follows `horn_in_play` ahead (`play_horizons`): the hand's push counts beyond
/// max(`backlash_torque`, `PLAY_TORQUE_MIN`) (between that and −that the side is kept), first at
/// the held horizon (the hand will hold the horn: the motor must be across by then), then at the
/// free one; within `backlash_torque` at the free horizon the horn is free of the hand and the
/// motor must push it in the direction of travel there (side −sgn ω), but only once the model
/// moves faster than `PLAY_VELOCITY_MIN`. A hand that pushes the way the joint moves thus has the
/// motor *behind* the horn (it resists the hand), and a motor that drives a free horn has it
/// *ahead*. The torque is the hand's extrapolated to each horizon, because the horn changes sides
/// the moment the hand's torque crosses ±q_b, at once, and the motor needs its own time to follow:
/// decided on the present torque, every crossing starts late and the horn sits the whole play off
/// at its start. The rate τ' is the difference of two first-order low-passes in cascade over half
/// `play_ahead` each (on a ramp exactly the rate times that time; the sensor's noise filtered
/// twice). At the free horizon (short) the torque is τ + τ'·horizon, the present torque itself
/// unfiltered so the decision is not late by a filter's lag; at the held horizon (up to a few
/// crossings) it is the first low-pass carried forward, τ̄ + τ'·(horizon + its time constant):
/// the same on a ramp, without the raw sensor noise the longer horizon would otherwise act on. At
/// rest the extrapolation is not used unless it predicts a change beyond the noise within a
/// crossing (|τ| or |τ'|·(dead time⁺ + `play_crossing`) beyond `PLAY_TORQUE_MIN`): torque noise
/// at rest within it, and speed noise within `PLAY_VELOCITY_MIN`, never flip the side. And the
/// horn is taken free (the direction-of-travel rule) only once the torque at the free horizon is
/// within q_b by at least the torque's measured noise σ (from its second differences over
/// `PLAY_NOISE_WINDOW`, white noise's variance being a sixth of theirs): a torque hovering at the
/// band's edge would otherwise flip the side between the push and the travel rules on each
/// noise sample, and each flip starts a crossing (the goal buzzing across the play, and the horn
/// off while it does). With the reference at rest (|ω| within `PLAY_VELOCITY_MIN`, a dead time
/// ahead) the held torque must pass the push by twice its own noise (`held_torque_noise` times
/// the measured variance): extrapolated over a few crossings, a noisy sensor's torque otherwise
/// crosses the push many times a minute with no hand on the horn, and each time the goal crosses
/// the play and back (the free horn does not move; the servo does).
///
/// **The crossing** is −side·backlash/2 through three first-order stages of a third of
/// `play_crossing` each (a critically damped crossing, mean delay `play_crossing`), plus the
/// servo's own inverse of that motion, T·(m·o'' + o'), from the stages' exact differences: the
/// motor then crosses in about the servo's natural time instead of lagging a ramp by its lag and
/// ringing after it, and the goal never steps by more than about the play itself.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlaySide {
    side: f64,
    /// The crossing's three stages (rad): the last is the motor's offset.
    stages: [f64; 3],
    /// The hand's torque through two first-order low-passes in cascade (N·m): their difference
    /// over their time constant is its rate.
    torque: [f64; 2],
    /// The last two torques (N·m; None before the first finite one) and the torque's noise
    /// variance (N·m²) from their second differences.
    last: Option<[f64; 2]>,
    noise: f64,
}

impl PlaySide {
    /// One cycle of `h` s: the reference moving at `omega` with acceleration `alpha` (the
    /// loop's, both now) under the hand torque `tau`. Returns the goal offset (rad). Non-finite
    /// inputs keep the side and the torque's filters (the offset stays finite).
    pub fn update(&mut self, model: &ServoModel, omega: f64, alpha: f64, tau: f64, h: f64) -> f64 {
        if model.backlash <= 0.0 {
            *self = PlaySide::default();
            return 0.0;
        }
        let h = if h > 0.0 { h } else { 0.0 }; // NaN or ≤ 0: the filters stand still
        let smoothing = 0.5 * play_ahead(model);
        if tau.is_finite() {
            let share = h / (smoothing + h);
            self.torque[0] += (tau - self.torque[0]) * share;
            self.torque[1] += (self.torque[0] - self.torque[1]) * share;
            self.measure_noise(tau, h);
        }
        let rate = (self.torque[0] - self.torque[1]) / smoothing;
        let (free, held) = play_horizons(model, omega + alpha * model.dead_time.max(0.0));
        let within_crossing = model.dead_time.max(0.0) + play_crossing(model);
        let extrapolate = tau.abs() > PLAY_TORQUE_MIN || (rate * within_crossing).abs() > PLAY_TORQUE_MIN;
        let (tau_free, tau_held) = if extrapolate {
            (tau + rate * free, self.torque[0] + rate * (held + smoothing))
        } else {
            (tau, tau)
        };
        let omega_free = omega + alpha * free;
        let push = model.backlash_torque.max(PLAY_TORQUE_MIN);
        let free_below = model.backlash_torque - self.noise.sqrt();
        let at_rest = (omega + alpha * model.dead_time.max(0.0)).abs() <= PLAY_VELOCITY_MIN;
        let held_beyond = if at_rest && self.noise > 0.0 && h > 0.0 {
            let spread = held_torque_noise(h / (smoothing + h), (held + smoothing) / smoothing);
            push + 2.0 * (self.noise * spread).sqrt()
        } else {
            push
        };
        if tau_held.abs() > held_beyond {
            self.side = tau_held.signum();
        } else if tau_free.abs() > push {
            self.side = tau_free.signum();
        } else if tau_free.abs() <= free_below && omega_free.abs() > PLAY_VELOCITY_MIN {
            self.side = -omega_free.signum();
        }
        let stage = play_crossing(model) / 3.0;
        let share = h / (stage + h);
        let mut input = -0.5 * model.backlash * self.side;
        for x in &mut self.stages {
            *x += (input - *x) * share;
            input = *x;
        }
        let [a, b, c] = self.stages;
        let (velocity, acceleration) = ((b - c) / stage, (a - 2.0 * b + c) / (stage * stage));
        c + model.time_constant * (model.inertial_time * acceleration + velocity)
    }

    /// The side the horn is taken to rest on (−1, 0, +1).
    pub fn side(&self) -> f64 {
        self.side
    }

    /// N·m: the hand torque's measured noise (standard deviation).
    pub fn torque_noise(&self) -> f64 {
        self.noise.sqrt()
    }

    /// One finite torque sample into the noise's variance: a sixth of the mean square of the
    /// second differences (exact for white noise; a hand's smooth push adds only τ''·h², about
    /// 10⁻⁴ N·m at 1 kHz), averaged over `PLAY_NOISE_WINDOW`.
    fn measure_noise(&mut self, tau: f64, h: f64) {
        let [a, b] = self.last.unwrap_or([tau, tau]);
        let second = tau - 2.0 * a + b;
        self.noise += (second * second / 6.0 - self.noise) * h / (PLAY_NOISE_WINDOW + h);
        self.last = Some([tau, a]);
    }
}

/// One recorded run of a servo: the times at which its horn angle is known (`t`), and its goal
/// and the hand torque on their own time base (`t_in`), linearly interpolated in between.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoTrial {
    t: Vec<f64>,
    t_in: Vec<f64>,
    goal: Vec<f64>,
    tau: Vec<f64>,
}

fn strictly_increasing(name: &str, t: &[f64]) -> Result<(), PlantError> {
    if t.is_empty() {
        return Err(PlantError::Shape(format!("{name} needs at least one sample")));
    }
    for (i, &v) in t.iter().enumerate() {
        require_finite(&format!("{name}[{i}]"), v)?;
    }
    match t.windows(2).position(|w| w[1] <= w[0]) {
        Some(i) => Err(PlantError::InvalidValue(format!("{name} must be strictly increasing at index {}", i + 1))),
        None => Ok(()),
    }
}

impl ServoTrial {
    pub fn new(t: Vec<f64>, t_in: Vec<f64>, goal: Vec<f64>, tau: Vec<f64>) -> Result<Self, PlantError> {
        strictly_increasing("t", &t)?;
        strictly_increasing("t_in", &t_in)?;
        for (name, series) in [("goal", &goal), ("tau", &tau)] {
            if series.len() != t_in.len() {
                return Err(PlantError::Shape(format!("{name} has {} samples but t_in has {}", series.len(), t_in.len())));
            }
            for (i, &v) in series.iter().enumerate() {
                require_finite(&format!("{name}[{i}]"), v)?;
            }
        }
        Ok(ServoTrial { t, t_in, goal, tau })
    }

    pub fn n_samples(&self) -> usize {
        self.t.len()
    }
}

/// Simulates `trial` from `x0` (the state at t[0]) and hands the state at every sample time to
/// `record(i, &state)`. Between samples it takes equal substeps of at most `max_step`, with the
/// goal interpolated at (substep time − dead time) and the torque at the substep time.
pub fn simulate_into<F: FnMut(usize, &State)>(trial: &ServoTrial, model: &ServoModel, x0: State, max_step: f64, mut record: F) {
    let mut goal = TorqueCursor::new(&trial.t_in, &trial.goal);
    let mut tau = TorqueCursor::new(&trial.t_in, &trial.tau);
    // x0 is the horn; the motor starts on the side of the play the first torque holds it to.
    let mut horn = x0.theta;
    let mut state = State { theta: x0.theta - (horn_in_play(model, 0.0, 0.0, tau.at(trial.t[0]))), ..x0 };
    walk(&trial.t, max_step, |event| match event {
        Walk::Substep { t, h } => {
            let q = tau.at(t);
            step(&mut state, model, goal.at(t - model.dead_time), q, h);
            horn = horn_in_play(model, horn, state.theta, q);
        }
        Walk::Sample(i) => record(i, &State { theta: horn, omega: state.omega }),
    });
}

/// The horn angle at every sample time of `trial`, after checking the inputs.
pub fn simulate(trial: &ServoTrial, model: &ServoModel, x0: State, max_step: f64) -> Result<Vec<f64>, PlantError> {
    model.validate()?;
    validate_max_step(max_step)?;
    require_finite("theta0", x0.theta)?;
    require_finite("omega0", x0.omega)?;
    let mut out = vec![0.0; trial.n_samples()];
    simulate_into(trial, model, x0, max_step, |i, s| out[i] = s.theta);
    Ok(out)
}

/// Every trial under every model, in parallel: `x0[s * trials.len() + k]` starts model `s` on
/// trial `k`. Returns one row-major (S, n_samples) buffer of angles per trial. Everything is
/// checked before any thread starts.
pub fn simulate_batch(
    trials: &[&ServoTrial],
    models: &[ServoModel],
    x0: &[State],
    max_step: f64,
) -> Result<Vec<Vec<f64>>, PlantError> {
    validate_max_step(max_step)?;
    for (s, m) in models.iter().enumerate() {
        m.validate().map_err(|e| PlantError::InvalidValue(format!("servo model {s}: {e}")))?;
    }
    if x0.len() != models.len() * trials.len() {
        return Err(PlantError::Shape(format!(
            "x0 has {} initial states, expected {} models × {} trials",
            x0.len(),
            models.len(),
            trials.len()
        )));
    }
    for (i, x) in x0.iter().enumerate() {
        require_finite(&format!("x0 theta #{i}"), x.theta)?;
        require_finite(&format!("x0 omega #{i}"), x.omega)?;
    }
    let n_sets = models.len();
    let mut outs: Vec<Vec<f64>> = trials.iter().map(|tr| vec![0.0; n_sets * tr.n_samples()]).collect();
    let mut jobs: Vec<(usize, usize, &mut [f64])> = Vec::with_capacity(n_sets * trials.len());
    for (k, out) in outs.iter_mut().enumerate() {
        for (s, chunk) in out.chunks_mut(trials[k].n_samples().max(1)).enumerate() {
            jobs.push((s, k, chunk));
        }
    }
    jobs.into_par_iter().for_each(|(s, k, chunk)| {
        simulate_into(trials[k], &models[s], x0[s * trials.len() + k], max_step, |i, st| chunk[i] = st.theta)
    });
    Ok(outs)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MX: ServoModel =
        ServoModel {
            time_constant: 0.017,
            inertial_time: 0.021,
            dead_time: 0.002,
            compliance: 0.024,
            deadband: 0.002,
            backlash: 0.0,
            backlash_torque: 0.0,
        };
    /// MX with the play of bench/servo_forms.py's geared oracle (0.5°, a horn friction of 0.02 N·m).
    const GEARED: ServoModel = ServoModel { backlash: 0.0087, backlash_torque: 0.02, ..MX };

    fn uniform(n: usize, dt: f64) -> Vec<f64> {
        (0..n).map(|i| i as f64 * dt).collect()
    }

    fn trial(goal: impl Fn(f64) -> f64, tau: impl Fn(f64) -> f64, seconds: f64) -> ServoTrial {
        let t = uniform((seconds * 1000.0) as usize, 1e-3);
        let g = t.iter().map(|&x| goal(x)).collect();
        let q = t.iter().map(|&x| tau(x)).collect();
        ServoTrial::new(t.clone(), t, g, q).unwrap()
    }

    #[test]
    fn a_first_order_lag_steps_like_implicit_euler_even_far_below_the_substep() {
        let tr = trial(|_| 1.0, |_| 0.0, 0.05);
        let out = simulate(&tr, &ServoModel::first_order_lag(1e-6), State::default(), 5e-4).unwrap();
        assert!(out.iter().skip(1).all(|&x| (x - 1.0).abs() < 1e-2), "no divergence");
        let (tc, h) = (0.025, 1e-4);
        let tr = trial(|_| 1.0, |_| 0.0, 0.2);
        let out = simulate(&tr, &ServoModel::first_order_lag(tc), State::default(), h).unwrap();
        for (i, &theta) in out.iter().enumerate() {
            let n = (i as f64 * 1e-3 / h).round();
            let exact = 1.0 - (1.0 / (1.0 + h / tc)).powf(n);
            assert!((theta - exact).abs() < 1e-9, "sample {i}: {theta} vs {exact}");
        }
        assert!((out[25] - (1.0 - (-1.0f64).exp())).abs() < 3e-3, "one time constant: 63 %");
    }

    #[test]
    fn a_ramp_is_followed_time_constant_plus_dead_time_behind_plus_the_deadband() {
        let v = 0.5;
        let tr = trial(|t| v * t, |_| 0.0, 2.0);
        let out = simulate(&tr, &MX, State::default(), 2.5e-4).unwrap();
        let lag = v * 1.999 - out[1999];
        let expected = v * (MX.time_constant + MX.dead_time) + MX.deadband;
        assert!((lag - expected).abs() < 2e-4, "lag {lag} vs {expected}");
    }

    #[test]
    fn absurd_servo_tables_are_refused_and_the_fit_s_own_domain_is_not() {
        let bad_values = [(3, 1e300), (3, -1e6), (4, 1e300), (2, 1.0), (0, 0.0), (1, -0.1), (0, f64::NAN)];
        let bad_play = [(5, -1e-3), (5, 0.04), (5, 1e300), (6, -0.1), (6, 2.5), (6, f64::INFINITY)];
        for (k, bad) in bad_values.into_iter().chain(bad_play) {
            let mut v = MX.to_array();
            v[k] = bad;
            assert!(ServoModel::from_slice(&v).is_err(), "{} = {bad}", SERVO_PARAM_NAMES[k]);
        }
        for (k, (lo, hi)) in SERVO_DOMAIN.iter().enumerate() {
            let mut v = MX.to_array();
            v[k] = if k == 0 { *hi } else { *lo };
            assert!(ServoModel::from_slice(&v).is_ok(), "{} at its bound", SERVO_PARAM_NAMES[k]);
        }
    }

    #[test]
    fn the_hand_deflects_the_horn_by_the_compliance_and_the_deadband_holds_it() {
        let tr = trial(|_| 0.0, |_| 0.5, 2.0);
        let deflection = MX.compliance * 0.5;
        let out = simulate(&tr, &MX, State::default(), 2.5e-4).unwrap();
        assert!((out[1999] - deflection).abs() <= MX.deadband, "the horn rests within the band: {}", out[1999]);
        let no_inertia = ServoModel { inertial_time: 0.0, ..MX };
        let out = simulate(&tr, &no_inertia, State::default(), 2.5e-4).unwrap();
        assert!((out[1999] - (deflection - MX.deadband)).abs() < 1e-9, "without inertia, at its edge: {}", out[1999]);
        let small = trial(|_| 0.0, |_| 0.5 * MX.deadband / MX.compliance, 1.0);
        let out = simulate(&small, &MX, State::default(), 2.5e-4).unwrap();
        assert!(out.iter().all(|&x| x == 0.0), "within the band the horn never moves");
    }

    #[test]
    fn the_play_holds_the_horn_where_the_hand_pushes_and_the_motor_drags_a_free_horn() {
        let half = 0.5 * GEARED.backlash;
        // At rest, a hand that pushes +, then −: the horn sits half the play to that side of the
        // motor, which itself gives by the compliance (without inertia and band: exactly).
        let soft = ServoModel { inertial_time: 0.0, deadband: 0.0, ..GEARED };
        let tr = trial(|_| 0.0, |t| if t < 1.0 { 0.3 } else { -0.3 }, 2.0);
        let out = simulate(&tr, &soft, State::default(), 2.5e-4).unwrap();
        assert!((out[999] - (0.3 * soft.compliance + half)).abs() < 1e-6, "pushed +: {}", out[999]);
        assert!((out[1999] - (-0.3 * soft.compliance - half)).abs() < 1e-6, "pushed −: {}", out[1999]);
        // No hand: a goal ramp drags the horn, which trails the motor by half the play.
        let ramp = trial(|t| 0.5 * t, |_| 0.0, 2.0);
        let free = simulate(&ramp, &GEARED, State::default(), 2.5e-4).unwrap();
        let rigid = simulate(&ramp, &MX, State::default(), 2.5e-4).unwrap();
        assert!((rigid[1999] - free[1999] - half).abs() < 1e-6, "trails by {}", rigid[1999] - free[1999]);
        // A hand within the horn's friction does not move it: after the ramp stops, it stays.
        let back = trial(|t| if t < 0.5 { 0.5 * t } else { 0.25 }, |_| 0.015, 1.5);
        let out = simulate(&back, &GEARED, State::default(), 2.5e-4).unwrap();
        let settled = simulate(&back, &MX, State::default(), 2.5e-4).unwrap();
        assert!((settled[1499] - out[1499] - half).abs() < 1e-4, "still trailing: {}", settled[1499] - out[1499]);
        // Without play the horn is the motor, bit for bit.
        assert_eq!(simulate(&ramp, &ServoModel { backlash_torque: 0.3, ..MX }, State::default(), 2.5e-4).unwrap(), rigid);
    }

    /// RMS of (horn − reference) after the first 0.5 s, with and without the play's inverse.
    fn play_errors(model: &ServoModel, tau: impl Fn(f64) -> f64 + Copy) -> (f64, f64) {
        let r = |t: f64| 0.2 * (2.0 * t).sin() + 0.05 * (9.0 * t).sin();
        let w = |t: f64| 0.4 * (2.0 * t).cos() + 0.45 * (9.0 * t).cos();
        let a = |t: f64| -0.8 * (2.0 * t).sin() - 4.05 * (9.0 * t).sin();
        let t: Vec<f64> = uniform(4000, 1e-3);
        let mut play = PlaySide::default();
        let offsets: Vec<f64> = t.iter().map(|&x| play.update(model, w(x), a(x), tau(x), 1e-3)).collect();
        let goal = |with: bool| -> Vec<f64> {
            t.iter().zip(&offsets).map(|(&x, o)| r(x) + lead(model, w(x), a(x), tau(x)) + if with { *o } else { 0.0 }).collect()
        };
        let q: Vec<f64> = t.iter().map(|&x| tau(x)).collect();
        let err = |g: Vec<f64>| {
            let tr = ServoTrial::new(t.clone(), t.clone(), g, q.clone()).unwrap();
            let out = simulate(&tr, model, State { theta: r(0.0), omega: w(0.0) }, 2.5e-4).unwrap();
            let sq: f64 = out.iter().enumerate().skip(500).map(|(i, y)| (y - r(i as f64 * 1e-3)).powi(2)).sum();
            (sq / (out.len() - 500) as f64).sqrt()
        };
        (err(goal(false)), err(goal(true)))
    }

    #[test]
    fn the_play_s_inverse_makes_the_horn_follow_whether_the_hand_or_the_motor_pushes() {
        // A hand that leans on the horn (|τ| well beyond its friction), and one that never does.
        for (name, tau) in [("motor", (|_: f64| 0.0) as fn(f64) -> f64), ("hand", |t: f64| 0.3 * (2.0 * t).cos())] {
            let (without, with) = play_errors(&GEARED, tau);
            // Measured 15.9× and 9.4× (the crossing shaped and driven by the servo's own inverse,
            // decided play_ahead early); without the drive, or decided on the present torque, < 8×.
            assert!(with < without / 8.0, "{name}: {without} → {with}");
        }
    }

    /// The offsets of a fresh `PlaySide` under the model at rest (ω = 0) and the torques `taus`.
    fn offsets(model: &ServoModel, taus: impl Iterator<Item = f64>, h: f64) -> (Vec<f64>, Vec<f64>) {
        let mut play = PlaySide::default();
        taus.map(|q| (play.update(model, 0.0, 0.0, q, h), play.side())).unzip()
    }

    #[test]
    fn the_play_s_inverse_does_not_chatter_on_noise_at_rest() {
        let h = 1e-3;
        // A fitted horn friction, and none (the sensor's noise is then all the push threshold has).
        for model in [GEARED, ServoModel { backlash_torque: 0.0, ..GEARED }] {
            let mut play = PlaySide::default();
            for _ in 0..200 {
                play.update(&model, 0.0, 0.0, 0.1, h);
            }
            // Deterministic "noise": torque within ±the sensor's noise, velocity within ±its own.
            let noise = |k: usize| (k as f64 * 0.7).sin() * (k as f64 * 1.3).cos();
            let rest = |play: &mut PlaySide, k: usize| {
                play.update(&model, 0.99 * PLAY_VELOCITY_MIN * noise(k), 0.0, 0.99 * PLAY_TORQUE_MIN * noise(k), h)
            };
            // The hand let go at once: its fall, extrapolated, may read as a fall on through the band
            // (once: the motor then goes to the other side of a free horn, which it does not move);
            // within the torque filters' settling (a few of their time constants) that is over.
            let (mut flips, mut side, mut last) = (0, play.side(), 0.0);
            for k in 0..(10.0 * play_ahead(&model) / h) as usize {
                rest(&mut play, k);
                flips += (play.side() != side) as u32;
                side = play.side();
            }
            assert!(flips <= 1, "a let-go flips the side at most once: {flips}");
            flips = 0;
            for k in 0..5000 {
                last = rest(&mut play, k + 1000);
                flips += (play.side() != side) as u32;
                side = play.side();
            }
            assert_eq!(flips, 0, "the side is kept at rest: {model:?}");
            assert_eq!(play.update(&model, f64::NAN, f64::NAN, f64::NAN, h), last, "non-finite input: kept");
        }
        assert_eq!(PlaySide::default().update(&MX, 1.0, 0.0, 1.0, h), 0.0, "no play, no offset");
    }

    #[test]
    fn a_reversal_of_the_hand_crosses_in_the_servo_s_own_time_without_stepping_the_goal_by_more_than_the_play() {
        let h = 1e-3;
        let slow = ServoModel { time_constant: 0.08, inertial_time: 0.05, ..GEARED };
        for model in [GEARED, slow] {
            let (half, crossing) = (0.5 * model.backlash, play_crossing(&model));
            let n = (12.0 * crossing / h) as usize;
            let (goal, _) = offsets(&model, (0..2 * n).map(|k| if k < n { 0.1 } else { -0.1 }), h);
            assert!((goal[n - 1] + half).abs() < 1e-6 && (goal[2 * n - 1] - half).abs() < 1e-6, "side to side");
            let most = goal.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
            assert!(most <= model.backlash, "a step of {most} for a play of {}", model.backlash);
            // The motor's offset (the goal less the servo's inverse of it) is half-way across after
            // about the crossing's mean delay: the servo's own time, not a constant.
            let mut play = PlaySide::default();
            let motor: Vec<f64> = (0..2 * n).map(|k| { play.update(&model, 0.0, 0.0, if k < n { 0.1 } else { -0.1 }, h); play.stages[2] }).collect();
            let mid = (n..2 * n).find(|&k| motor[k] >= 0.0).unwrap() - n;
            assert!((0.7..1.1).contains(&(mid as f64 * h / crossing)), "half-way after {mid} cycles, crossing {crossing}");
        }
    }

    #[test]
    fn the_side_is_decided_early_enough_to_be_nearly_across_when_the_hand_takes_hold_at_rest() {
        let h = 1e-3;
        // The hand's torque falls at 0.5 N·m/s from +0.2 through the play's band to −0.2, the joint
        // at rest: the hand will hold the horn on the other side, and the motor must be across by
        // then. The side flips the held horizon before the torque passes −push (with the reference
        // at rest: a few stage times, more than a whole crossing), so that the motor's offset is
        // nearly across when the hand takes hold. (A whole crossing early, the rule of before,
        // left 42 % of the play to go: the horn jumped by that when the hand took hold.)
        let push = GEARED.backlash_torque.max(PLAY_TORQUE_MIN);
        let tau = |k: usize| 0.2 - 0.5 * k as f64 * h;
        let mut play = PlaySide::default();
        let (motor, sides): (Vec<f64>, Vec<f64>) =
            (0..800).map(|k| { play.update(&GEARED, 0.0, 0.0, tau(k), h); (play.stages[2], play.side()) }).unzip();
        let flip = sides.iter().position(|&s| s < 0.0).expect("it flips");
        let now = (0..800).find(|&k| tau(k) < -push).unwrap();
        let early = (now - flip) as f64 * h;
        let (_, held) = play_horizons(&GEARED, 0.0);
        assert!(held > GEARED.dead_time + play_crossing(&GEARED), "at rest: more than a crossing, {held}");
        assert!((early - held).abs() <= 2.0 * h, "{early} s early, held horizon {held}");
        let across = (motor[now] + 0.5 * GEARED.backlash) / GEARED.backlash;
        assert!(across > 0.85, "{across} of the way across when the hand takes hold");
    }

    /// Deterministic white noise: uniform in ±√3·σ (a linear congruential generator).
    fn white(seed: &mut u64, sigma: f64) -> f64 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * 3f64.sqrt() * sigma
    }

    #[test]
    fn a_noisy_hand_letting_go_while_the_joint_moves_flips_the_side_less_than_on_every_noise_sample() {
        // The joint moves on at 0.1 rad/s; the hand holds the horn (0.1 N·m) and lets go (0),
        // 20 times, through ramps of 1 N·m/s, its sensor carrying white noise of 5 mN·m (a quarter
        // of the horn's friction). Each let-go and each take-hold moves the side once (40 flips);
        // taken free at the very edge of the friction, a torque passing it flipped the side
        // between the push and the travel rules on the noise (204 flips without the noise margin,
        // 142 with it: a margin of one σ thins the chatter, it does not end it; deterministic noise).
        let (h, sigma, omega) = (1e-3, 0.005, 0.1);
        let mut seed = 7;
        let mut play = PlaySide::default();
        let tau = |k: usize| {
            let phase = k % 600;
            (if phase < 300 { 0.1 - 1e-3 * phase as f64 } else { 1e-3 * (phase - 300) as f64 - 0.2 }).clamp(0.0, 0.1)
        };
        let (mut flips, mut side) = (0, 0.0);
        for k in 0..12000 {
            let noise: f64 = (0..3).map(|_| white(&mut seed, sigma)).sum::<f64>() / 3f64.sqrt();
            play.update(&GEARED, omega, 0.0, tau(k) + noise, h);
            flips += (k > 0 && play.side() != side) as u32;
            side = play.side();
        }
        assert!((play.torque_noise() - sigma).abs() < 0.2 * sigma, "measured noise {}", play.torque_noise());
        assert!(flips < 170, "{flips} flips");
    }

    #[test]
    fn a_noisy_sensor_at_rest_does_not_make_the_goal_buzz_across_the_play() {
        // No hand on the horn, the joint at rest, 60 s of white torque noise of 5 mN·m (a quarter
        // of the horn's friction) and speed noise of 5 mrad/s: the held torque, extrapolated over
        // a few crossings, crossed the push many times a minute; beyond twice its own noise it
        // does a few times (measured 1 with the margin, 144 without; deterministic noise).
        let (h, sigma) = (1e-3, 0.005);
        let mut seed = 11;
        let mut play = PlaySide::default();
        let (mut flips, mut side) = (0, 0.0);
        for _ in 0..60000 {
            let noise: f64 = (0..3).map(|_| white(&mut seed, sigma)).sum::<f64>() / 3f64.sqrt();
            let speed = white(&mut seed, 0.005);
            play.update(&GEARED, speed, 0.0, noise, h);
            flips += (play.side() != side) as u32;
            side = play.side();
        }
        assert!(flips <= 10, "{flips} flips in a minute at rest");
    }

    #[test]
    fn the_held_torque_s_noise_is_its_filter_s_impulse_response_squared() {
        // Test ORACLE: the two low-passes' impulse responses summed numerically.
        for (share, c) in [(0.15, 8.0), (0.05, 3.0), (0.5, 1.0)] {
            let (mut zero, mut one, mut sum) = (share, share * share, 0.0);
            for _ in 0..20000 {
                sum += ((1.0 + c) * zero - c * one) * ((1.0 + c) * zero - c * one);
                zero *= 1.0 - share;
                one = one * (1.0 - share) + share * zero;
            }
            assert!((held_torque_noise(share, c) - sum).abs() < 1e-9 * sum, "{share}, {c}: {} vs {sum}", held_torque_noise(share, c));
        }
    }

    /// Test ORACLE of `held_lead`'s cost (in β²·stage): the free horn left early falls behind at
    /// r per stage time, r²·u³/3; the share of the crossing left when the hand takes hold shows
    /// whole, ∫ from u of the three stages' survival squared (by the trapezoid rule, written from
    /// the Erlang survival, not from `crossing_left`).
    fn held_cost(r: f64, u: f64) -> f64 {
        let left = |s: f64| (-s).exp() * (1.0 + s + s * s / 2.0);
        let ds = 1e-3;
        let n = ((60.0 - u) / ds) as usize;
        let after: f64 = (0..n).map(|i| 0.5 * ds * (left(u + i as f64 * ds).powi(2) + left(u + (i + 1) as f64 * ds).powi(2))).sum();
        r * r * u.powi(3) / 3.0 + after
    }

    #[test]
    fn the_held_horizon_is_where_the_error_left_before_and_after_the_hand_takes_hold_is_least() {
        for r in [0.003, 0.03, 0.1, 0.5, 2.0] {
            let u = held_lead(r);
            let best = held_cost(r, u);
            for other in [0.8 * u, 0.9 * u, 1.1 * u, 1.25 * u, 3.0] {
                assert!(best <= held_cost(r, other) + 1e-12, "r {r}: {u} costs {best}, {other} {}", held_cost(r, other));
            }
        }
        // Slower references are crossed to earlier; a bad rate gives a bounded horizon.
        assert!(held_lead(0.01) > held_lead(0.1) && held_lead(0.1) > held_lead(1.0));
        for bad in [f64::NAN, 0.0, -1.0, f64::INFINITY] {
            let u = held_lead(bad);
            assert!(u.is_finite() && (0.0..=40.0).contains(&u), "{bad}: {u}");
        }
    }

    #[test]
    fn a_free_horn_is_crossed_to_only_as_early_as_a_slow_reference_runs_away() {
        let h = 1e-3;
        // The hand lets go (its torque falls at 0.5 N·m/s from +0.2 to 0 and stays) while the
        // joint moves on slowly: the motor must go ahead of the horn (side −1) once the hand no
        // longer holds it, but the free horn falls behind only at the reference's speed, so the
        // crossing starts the free horizon early (a share of half a crossing), not play_ahead.
        let omega = 0.05;
        let tau = |k: usize| (0.2 - 0.5 * k as f64 * h).max(0.0);
        let mut play = PlaySide::default();
        let sides: Vec<f64> = (0..800).map(|k| { play.update(&GEARED, omega, 0.0, tau(k), h); play.side() }).collect();
        let flip = sides.iter().position(|&s| s < 0.0).expect("it flips");
        let now = (0..800).find(|&k| tau(k) <= GEARED.backlash_torque).unwrap();
        let early = now as f64 * h - flip as f64 * h;
        let (free, held) = play_horizons(&GEARED, omega + 0.0);
        assert!(free < 0.5 * play_ahead(&GEARED) && held > play_ahead(&GEARED), "free {free}, held {held}");
        assert!((early - free).abs() <= 2.0 * h, "{early} s early, free horizon {free}");
        // A reference that runs away by half the play within a crossing: the free horizon is
        // play_ahead; the held one is shorter than at the slow speed (a free horn left early falls
        // behind faster), and at rest it is the slowest speed's (PLAY_VELOCITY_MIN: noise).
        let fast = GEARED.backlash / play_crossing(&GEARED);
        let (free, fast_held) = play_horizons(&GEARED, fast);
        assert!((free - play_ahead(&GEARED)).abs() < 1e-12 && fast_held < held, "{free}, {fast_held} vs {held}");
        assert_eq!(play_horizons(&GEARED, 0.0).1, play_horizons(&GEARED, -PLAY_VELOCITY_MIN).1);
        // Far faster, the balance would start after the switch's centre; a hand reversing through
        // the band holds the horn the other way until then: no later than play_ahead.
        assert!((play_horizons(&GEARED, 20.0 * fast).1 - play_ahead(&GEARED)).abs() < 1e-12);
    }

    #[test]
    fn the_play_s_offset_stays_within_a_few_plays_for_every_servo_in_the_domain() {
        let h = 1e-3;
        for (t, m, d) in [(1e-4, 0.0, 0.0), (1e-4, 0.5, 0.2), (1.0, 0.0, -0.02), (1.0, 0.5, 0.2), (0.02, 1e-4, 0.0)] {
            let model = ServoModel { time_constant: t, inertial_time: m, dead_time: d, backlash: 0.035, ..GEARED };
            let (goal, _) = offsets(&model, (0..20000).map(|k| if (k / 700) % 2 == 0 { 0.1 } else { -0.1 }), h);
            let (most, big) = goal.windows(2).fold((0.0, 0.0), |(s, b): (f64, f64), w| (s.max((w[1] - w[0]).abs()), b.max(w[1].abs())));
            assert!(big <= 2.0 * model.backlash && most <= 2.0 * model.backlash, "{model:?}: |offset| {big}, step {most}");
        }
    }

    #[test]
    fn the_dead_time_shifts_the_response() {
        let late = ServoModel { dead_time: 0.05, ..ServoModel::first_order_lag(0.01) };
        let tr = trial(|t| if t >= 0.1 { 1.0 } else { 0.0 }, |_| 0.0, 0.5);
        let out = simulate(&tr, &late, State::default(), 1e-4).unwrap();
        assert_eq!(out[149], 0.0, "nothing before 0.1 + 0.05 s");
        assert!(out[152] > 0.0);
    }

    #[test]
    fn the_lead_makes_the_horn_follow_the_reference() {
        // A reference with the admittance model's smoothness: a sum of sines, its ω and α exact.
        let r = |t: f64| 0.2 * (2.0 * t).sin() + 0.05 * (9.0 * t).sin();
        let w = |t: f64| 0.4 * (2.0 * t).cos() + 0.45 * (9.0 * t).cos();
        let a = |t: f64| -0.8 * (2.0 * t).sin() - 4.05 * (9.0 * t).sin();
        let tau = |t: f64| 0.3 * (3.0 * t).sin();
        for model in [MX, ServoModel { dead_time: 0.004, ..ServoModel::first_order_lag(0.025) }] {
            let plain = trial(r, tau, 4.0);
            let led = trial(|t| r(t) + lead(&model, w(t), a(t), tau(t)), tau, 4.0);
            let x0 = State { theta: r(0.0), omega: w(0.0) };
            let err = |out: Vec<f64>| {
                let sq: f64 = out.iter().enumerate().skip(500).map(|(i, y)| (y - r(i as f64 * 1e-3)).powi(2)).sum();
                (sq / (out.len() - 500) as f64).sqrt()
            };
            let before = err(simulate(&plain, &model, x0, 2.5e-4).unwrap());
            let after = err(simulate(&led, &model, x0, 2.5e-4).unwrap());
            assert!(after < before / 10.0, "{model:?}: {before} → {after}");
        }
    }

    #[test]
    fn the_batch_equals_single_runs_and_refuses_bad_models() {
        let a = trial(|t| t.sin(), |t| 0.1 * t.cos(), 1.0);
        let b = trial(|t| 0.3 * t, |_| 0.2, 0.5);
        let models = [MX, ServoModel::first_order_lag(0.03)];
        let x0 = vec![State::default(); 4];
        let outs = simulate_batch(&[&a, &b], &models, &x0, 5e-4).unwrap();
        for (s, m) in models.iter().enumerate() {
            let single = simulate(&b, m, State::default(), 5e-4).unwrap();
            assert_eq!(&outs[1][s * b.n_samples()..(s + 1) * b.n_samples()], &single[..]);
        }
        let bad = ServoModel { time_constant: 0.0, ..MX };
        assert!(simulate_batch(&[&a], &[bad], &x0[..1], 5e-4).unwrap_err().to_string().contains("time_constant"));
        assert!(ServoModel::from_slice(&[0.01, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0]).is_err());
        assert!(ServoModel::from_slice(&[0.01, 0.0, 0.0, 0.0, f64::NAN, 0.0, 0.0]).is_err());
        assert!(ServoModel::from_slice(&[0.01, 0.0, 0.0, 0.0, 0.0]).is_err(), "all seven values");
        assert_eq!(ServoModel::from_slice(&MX.to_array()).unwrap(), MX);
    }
}
