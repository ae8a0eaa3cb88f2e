//! Servo faults, detected and acted on: one recovery state machine per joint, spread over cycles.
//!
//! What it watches (fed by the cycle after every transaction, `observe`):
//! - the hardware alert on any status packet (P2 bit 7; P1's voltage, overheating and overload
//!   bits), which the SyncRead of the present positions brings for free;
//! - Torque Enable, read from one joint every `check_period_ns` in turn (a round-robin that
//!   costs one short READ per period): a servo found with torque off and no error (a brown-out's
//!   reset, another client's write) raises no alert;
//! - answers: a servo that has not answered for `silent_after_ns` is *silent* (held), one silent
//!   for `lost_timeout_ns` is lost (stop; a restart may find it again).
//!
//! What it does (docs/faults.md has the table), each step one transaction of one cycle, so a
//! step that waits (a reboot's silence) waits across cycles and never inside one:
//!
//! ```text
//! alert ──────▶ Diagnose ──▶ CheckTorque ── on, no error ──▶ Ok (a false alarm)
//! torque 0 ───▶ (read Hardware   (read Torque ── on, a safe error ──▶ Ok, the error tolerated:
//! (round-robin)  Error Status)    Enable)                        the firmware did not shut down
//!                                    │ off, an error: safe? ──▶ Reboot ─▶ Rebooting ─┐
//!                                    │                 (P1: AwaitClear until it clears)┤
//!                                    │ off, no error: reenable? ──────────────────────▶ Reanchor
//!                                    ▼                          (read the present position: the
//!                                 Stopped                        model starts where the horn is)
//! Ok ◀── on ── Verify ◀── Enable (torque on, after a SyncWrite that carried goal = present)
//!                │ off: the shutdown persists ─▶ Diagnose
//! ```
//!
//! An unsafe error (below) stops whether torque is on or off. Every refusal ends in `Stopped`, which latches a [`StopRequest`] the supervisor turns into an
//! exit status. A reboot is *safe* when the error is one a reboot cures and that does not hurt
//! the motor when torque comes back: an input-voltage dip, or an overload that did not repeat
//! within `recovery_window_ns`. Never for overheating (a hot motor), encoder or electrical-shock
//! errors (the servo is damaged or miswired), and never more than `max_recoveries` per joint
//! per window. While a joint recovers it holds (its model frozen at its last good state); the
//! re-anchor puts the model where the horn is, goal = present before torque on, so nothing jumps.
//!
//! Pure logic on a clock passed in: tested without a bus or a thread, and allocation-free.
use crate::fault::{FaultKind, Faults};

/// Hardware Error Status bits (P2 layout; P1's error byte has voltage, overheating and overload
/// at the same positions).
pub const HW_INPUT_VOLTAGE: u8 = 0x01;
pub const HW_OVERHEATING: u8 = 0x04;
pub const HW_ENCODER: u8 = 0x08;
pub const HW_ELECTRICAL_SHOCK: u8 = 0x10;
pub const HW_OVERLOAD: u8 = 0x20;
/// Errors never answered with a reboot: the reboot would clear the bit, not the cause.
pub const UNSAFE_HARDWARE_ERRORS: u8 = HW_OVERHEATING | HW_ENCODER | HW_ELECTRICAL_SHOCK;
/// The most recoveries per joint a window may allow (the history is a fixed ring).
pub const MAX_RECOVERIES_LIMIT: u32 = 16;
/// No Dynamixel's horn turns faster than this unloaded (the XL330-M077's 383 rpm is 40 rad/s).
pub const HORN_SPEED_MAX_DEFAULT: f64 = 50.0;
/// What `horn_speed_max` may be set to (rad/s): above 1000 no read would ever be a glitch.
pub const HORN_SPEED_MAX_RANGE: (f64, f64) = (1.0, 1000.0);
/// A failed step is tried again after this (a silent servo then costs a read timeout per 10 ms,
/// not per cycle).
const RETRY_NS: u64 = 10_000_000;
/// A rebooting servo is asked whether it is back this often...
const REBOOT_POLL_NS: u64 = 50_000_000;
/// ...but not before this: a servo still answering just after the REBOOT is not back yet.
const REBOOT_FIRST_POLL_NS: u64 = 100_000_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnServoError {
    /// Reboot where safe (see the module doc), then re-enable torque.
    Reboot,
    /// Stop the daemon.
    Stop,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnTorqueOff {
    /// Goal = present, then torque on again.
    Reenable,
    Stop,
}

/// The fault policy (`[faults]` in the daemon's configuration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultPolicy {
    pub servo_error: OnServoError,
    pub torque_off: OnTorqueOff,
    /// The bus (its port) or a servo not answering for this long: stop (`BusLost`, `ServoLost`).
    pub lost_timeout_ns: u64,
    /// A servo not answering for this long is silent: its joint holds.
    pub silent_after_ns: u64,
    /// Recoveries (reboots, re-enables) allowed per joint within `recovery_window_ns`.
    pub max_recoveries: u32,
    pub recovery_window_ns: u64,
    /// One joint's Torque Enable is read this often, in turn.
    pub check_period_ns: u64,
    /// The fastest any horn can turn (rad/s): a position read implying more is a glitch
    /// (`anchor`): kept out of the model, the goal and the record until a second read confirms it.
    pub horn_speed_max: f64,
}

impl Default for FaultPolicy {
    fn default() -> Self {
        FaultPolicy {
            servo_error: OnServoError::Reboot,
            torque_off: OnTorqueOff::Reenable,
            lost_timeout_ns: 5_000_000_000,
            silent_after_ns: 100_000_000,
            max_recoveries: 3,
            recovery_window_ns: 60_000_000_000,
            check_period_ns: 100_000_000,
            horn_speed_max: HORN_SPEED_MAX_DEFAULT,
        }
    }
}

impl FaultPolicy {
    pub fn validate(&self) -> Result<(), String> {
        if self.max_recoveries > MAX_RECOVERIES_LIMIT {
            return Err(format!("faults.max_recoveries must be at most {MAX_RECOVERIES_LIMIT}, got {}", self.max_recoveries));
        }
        for (name, ns) in [
            ("lost_timeout", self.lost_timeout_ns),
            ("silent_after", self.silent_after_ns),
            ("recovery_window", self.recovery_window_ns),
            ("check_period", self.check_period_ns),
        ] {
            if ns == 0 {
                return Err(format!("faults.{name} must be > 0"));
            }
        }
        if !(HORN_SPEED_MAX_RANGE.0..=HORN_SPEED_MAX_RANGE.1).contains(&self.horn_speed_max) {
            let (lo, hi) = HORN_SPEED_MAX_RANGE;
            return Err(format!("faults.horn_speed_max must be within {lo}..{hi} rad/s, got {}", self.horn_speed_max));
        }
        if self.silent_after_ns >= self.lost_timeout_ns {
            return Err("faults: a servo must be silent (servo_silent_ms) before it is lost (bus_lost_timeout_s)".into());
        }
        Ok(())
    }
}

/// Why the loop asks to be stopped. The supervisor maps each to an exit status (docs/faults.md):
/// what a restart may cure (a lost bus or servo) apart from what needs a person.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum StopCause {
    /// The bus's port failed and did not come back within `lost_timeout_ns`.
    BusLost = 1,
    /// A servo did not answer for `lost_timeout_ns` (a reboot that never came back included).
    ServoLost = 2,
    /// A hardware error under `servo_error = "stop"`.
    ServoErrorPolicy = 3,
    /// A hardware error a reboot must not answer (overheating, encoder, electrical shock).
    UnsafeError = 4,
    /// A second overload within the recovery window.
    RepeatedOverload = 5,
    /// More than `max_recoveries` within the window.
    TooManyRecoveries = 6,
    /// Torque found off under `torque_off = "stop"`.
    TorqueOffPolicy = 7,
    /// Protocol 1.0 (no REBOOT): the error bits did not clear within `lost_timeout_ns`.
    ErrorPersists = 8,
}

impl StopCause {
    pub const ALL: [StopCause; 8] = [
        StopCause::BusLost,
        StopCause::ServoLost,
        StopCause::ServoErrorPolicy,
        StopCause::UnsafeError,
        StopCause::RepeatedOverload,
        StopCause::TooManyRecoveries,
        StopCause::TorqueOffPolicy,
        StopCause::ErrorPersists,
    ];

    pub const fn name(self) -> &'static str {
        match self {
            StopCause::BusLost => "bus_lost",
            StopCause::ServoLost => "servo_lost",
            StopCause::ServoErrorPolicy => "servo_error_policy",
            StopCause::UnsafeError => "unsafe_hardware_error",
            StopCause::RepeatedOverload => "repeated_overload",
            StopCause::TooManyRecoveries => "too_many_recoveries",
            StopCause::TorqueOffPolicy => "torque_off_policy",
            StopCause::ErrorPersists => "error_persists",
        }
    }

    pub fn from_code(code: u8) -> Option<StopCause> {
        StopCause::ALL.into_iter().find(|c| *c as u8 == code)
    }
}

/// The loop's request to be stopped: the first cause wins, and it stays.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StopRequest {
    pub cause: StopCause,
    /// The joint (index) it concerns; None for the bus.
    pub joint: Option<usize>,
    /// Its Hardware Error Status when the cause is an error.
    pub hardware_error: u8,
}

impl StopRequest {
    /// One word, so another thread reads it whole: 0 = none.
    pub fn encode(req: Option<StopRequest>) -> u64 {
        req.map_or(0, |r| {
            let joint = r.joint.map_or(0xFFFF, |k| k.min(0xFFFE) as u64);
            1 << 63 | (r.cause as u64) | u64::from(r.hardware_error) << 8 | joint << 16
        })
    }

    pub fn decode(word: u64) -> Option<StopRequest> {
        if word >> 63 == 0 {
            return None;
        }
        let joint = (word >> 16) & 0xFFFF;
        Some(StopRequest {
            cause: StopCause::from_code(word as u8)?,
            hardware_error: (word >> 8) as u8,
            joint: (joint != 0xFFFF).then_some(joint as usize),
        })
    }
}

/// One servo transaction the recovery asks the cycle for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    ReadHardwareError,
    ReadTorqueEnable,
    Reboot,
    ReadPresent,
    EnableTorque,
}

/// What the recovery would do next (`Recovery::pick`): a joint's recovery step, a torque check
/// of a joint that just came back, or the round-robin's check of this joint (if it is `Ok`).
#[derive(Debug, Clone, Copy)]
enum Pick {
    Step(usize, Action),
    CheckDue(usize),
    RoundRobin(usize),
}

/// Where a joint's recovery stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    Ok,
    Diagnose,
    CheckTorque,
    Reboot,
    Rebooting { since_ns: u64 },
    AwaitClear { since_ns: u64 },
    Reanchor,
    Enable,
    Verify,
    Stopped,
}

impl Phase {
    /// Names of `code()`, for the stats.
    pub const NAMES: [&'static str; 10] =
        ["ok", "diagnosing", "checking_torque", "rebooting", "rebooting", "awaiting_clear", "reanchoring", "enabling", "verifying", "stopped"];

    pub fn code(self) -> u8 {
        match self {
            Phase::Ok => 0,
            Phase::Diagnose => 1,
            Phase::CheckTorque => 2,
            Phase::Reboot => 3,
            Phase::Rebooting { .. } => 4,
            Phase::AwaitClear { .. } => 5,
            Phase::Reanchor => 6,
            Phase::Enable => 7,
            Phase::Verify => 8,
            Phase::Stopped => 9,
        }
    }
}

/// Counters of one servo's faults and recoveries.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServoCounts {
    /// Recoveries started by a hardware error that shut the servo down.
    pub errors: u64,
    /// Hardware errors the firmware did not shut down for (torque still on): counted, run on.
    pub tolerated: u64,
    /// Recoveries started by torque found off.
    pub torque_offs: u64,
    pub reboots: u64,
    pub reenables: u64,
    /// Recoveries completed (torque verified on again).
    pub recoveries: u64,
    /// Times it went silent.
    pub silences: u64,
}

#[derive(Debug, Clone, Copy)]
struct Servo {
    phase: Phase,
    /// What it is recovering from (ServoError or TorqueOff).
    cause: Option<FaultKind>,
    /// The last status packet had the alert set.
    alert: bool,
    hardware_error: u8,
    /// An error the firmware runs on with (torque still on): its alerts start no diagnosis.
    tolerated: u8,
    /// The bits of the last error counted (a shutdown or a tolerated one), kept after recovery.
    last_error: u8,
    /// The first unanswered attempt since the last answer.
    unanswered_since: Option<u64>,
    silent: bool,
    /// A torque check is due before the round-robin's (it just came back).
    check_due: bool,
    next_ns: u64,
    history: [u64; MAX_RECOVERIES_LIMIT as usize],
    history_len: usize,
    last_overload_ns: Option<u64>,
    counts: ServoCounts,
    /// The state of the anchor retries' jitter (`retry_jitter_ns`), never 0.
    jitter: u32,
}

impl Servo {
    fn new() -> Self {
        Servo {
            phase: Phase::Ok,
            cause: None,
            alert: false,
            hardware_error: 0,
            tolerated: 0,
            last_error: 0,
            unanswered_since: None,
            silent: false,
            check_due: false,
            next_ns: 0,
            history: [0; MAX_RECOVERIES_LIMIT as usize],
            history_len: 0,
            last_overload_ns: None,
            counts: ServoCounts::default(),
            jitter: 0x9E37_79B9,
        }
    }

    /// A delay in [0, RETRY_NS) drawn anew each call (xorshift32: no allocation, no clock).
    ///
    /// Why: a refused anchor read is read again later, and at a fixed interval the anchor reads
    /// keep one phase against the reads between them (the SyncRead's, one per cycle): an encoder
    /// that glitches periodically can then hit every anchor read, and the joint never re-anchors
    /// (every third read out of range, 10 ms retries landing 11 cycles apart: 12 reads, every
    /// anchor read glitched; recovery_tests.rs `a_periodic_glitch_cannot_starve_a_re_anchor`).
    fn retry_jitter_ns(&mut self) -> u64 {
        let mut x = self.jitter;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.jitter = x;
        u64::from(x) % RETRY_NS
    }

    fn enter(&mut self, phase: Phase, next_ns: u64) {
        self.phase = phase;
        self.next_ns = next_ns;
    }
}

/// A joint's state as the statistics show it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServoView {
    pub phase: Phase,
    /// The last Hardware Error Status read (0 once recovered), or the one tolerated.
    pub hardware_error: u8,
    /// The bits of the last error counted in `counts` (shut down or tolerated), kept after the
    /// recovery: a reader that looks once a second still names the cause of a fast reboot.
    pub last_error: u8,
    pub silent: bool,
    pub counts: ServoCounts,
}

/// The recovery of every joint, and the loop's stop request.
pub struct Recovery {
    policy: FaultPolicy,
    /// Protocol 2.0: errors are answered with a REBOOT (Protocol 1.0 has none).
    can_reboot: bool,
    /// The loop drives the torque (it turned it on at start): only then may it turn it on again.
    acts: bool,
    servos: Vec<Servo>,
    next_check_ns: u64,
    round_robin: usize,
    stop: Option<StopRequest>,
}

impl Recovery {
    pub fn new(joints: usize, policy: FaultPolicy, can_reboot: bool, acts: bool) -> Self {
        Recovery { policy, can_reboot, acts, servos: vec![Servo::new(); joints], next_check_ns: 0, round_robin: 0, stop: None }
    }

    pub fn policy(&self) -> &FaultPolicy {
        &self.policy
    }

    /// What the last transaction to joint `k` showed: whether it answered, with the alert or not.
    pub fn observe(&mut self, k: usize, answered: bool, alert: bool, now_ns: u64) {
        let silent_after = self.policy.silent_after_ns;
        let acts = self.acts;
        let Some(s) = self.servos.get_mut(k) else { return };
        if !answered {
            let since = *s.unanswered_since.get_or_insert(now_ns);
            let rebooting = matches!(s.phase, Phase::Rebooting { .. });
            if !s.silent && !rebooting && now_ns.saturating_sub(since) >= silent_after {
                s.silent = true;
                s.counts.silences += 1;
            }
            return;
        }
        s.unanswered_since = None;
        if std::mem::take(&mut s.silent) {
            s.check_due = true; // back after a silence: was it reset (torque off)?
        }
        s.alert = alert;
        if alert && acts && s.phase == Phase::Ok && s.tolerated == 0 {
            s.cause = Some(FaultKind::ServoError);
            s.enter(Phase::Diagnose, now_ns);
        }
    }

    /// The transaction to make this cycle, if any: a recovery step that is due, else a torque
    /// check (one who just came back first, then the round-robin's).
    pub fn next_action(&mut self, now_ns: u64) -> Option<(usize, Action)> {
        match self.pick(now_ns)? {
            Pick::Step(k, action) => Some((k, action)),
            Pick::CheckDue(k) => {
                self.servos[k].check_due = false;
                Some((k, Action::ReadTorqueEnable))
            }
            Pick::RoundRobin(k) => {
                self.next_check_ns = now_ns + self.policy.check_period_ns;
                self.round_robin = (k + 1) % self.servos.len();
                (self.servos[k].phase == Phase::Ok).then_some((k, Action::ReadTorqueEnable))
            }
        }
    }

    /// Whether `next_action` would make a transaction now; takes nothing. The cycle asks it when
    /// the bus has no time left, to count how long the recovery has been kept waiting.
    pub fn wants_action(&self, now_ns: u64) -> bool {
        match self.pick(now_ns) {
            None => false,
            Some(Pick::RoundRobin(k)) => self.servos[k].phase == Phase::Ok,
            Some(_) => true,
        }
    }

    /// What is due now, in `next_action`'s order, without taking it.
    fn pick(&self, now_ns: u64) -> Option<Pick> {
        if self.stop.is_some() {
            return None;
        }
        let step = self.servos.iter().enumerate().find_map(|(k, s)| {
            let action = match s.phase {
                Phase::Ok | Phase::Stopped => return None,
                _ if now_ns < s.next_ns => return None,
                Phase::Diagnose => Action::ReadHardwareError,
                Phase::AwaitClear { .. } => Action::ReadHardwareError,
                Phase::CheckTorque | Phase::Verify | Phase::Rebooting { .. } => Action::ReadTorqueEnable,
                Phase::Reboot => Action::Reboot,
                Phase::Reanchor => Action::ReadPresent,
                Phase::Enable => Action::EnableTorque,
            };
            Some(Pick::Step(k, action))
        });
        if step.is_some() || !self.acts {
            return step;
        }
        if let Some(k) = self.servos.iter().position(|s| s.check_due && s.phase == Phase::Ok && !s.silent) {
            return Some(Pick::CheckDue(k));
        }
        if now_ns < self.next_check_ns || self.servos.is_empty() {
            return None;
        }
        Some(Pick::RoundRobin(self.round_robin % self.servos.len()))
    }

    /// The result of `action` on joint `k`: the value read (bits, 0/1, a tick; 0 for a write),
    /// or `Err` when the servo did not answer or refused.
    pub fn on_result(&mut self, k: usize, action: Action, result: Result<i64, ()>, now_ns: u64) {
        let Some(s) = self.servos.get(k) else { return };
        let phase = s.phase;
        let Ok(value) = result else {
            if !matches!(phase, Phase::Ok | Phase::Rebooting { .. } | Phase::AwaitClear { .. } | Phase::Stopped) {
                let jitter = if phase == Phase::Reanchor { self.servos[k].retry_jitter_ns() } else { 0 };
                self.servos[k].next_ns = now_ns + RETRY_NS + jitter;
            }
            if let Phase::Rebooting { .. } = phase {
                self.servos[k].next_ns = now_ns + REBOOT_POLL_NS;
            }
            return;
        };
        match (phase, action) {
            // Not a fault yet: the diagnosis reads Torque Enable again, and only a second 0
            // (torque_found_off) marks and counts it (a late reply once read as 0 did).
            (Phase::Ok, Action::ReadTorqueEnable) if value == 0 && self.acts => {
                self.servos[k].enter(Phase::Diagnose, now_ns);
            }
            (Phase::Diagnose, Action::ReadHardwareError) => {
                self.servos[k].hardware_error = value as u8;
                self.servos[k].enter(Phase::CheckTorque, now_ns);
            }
            (Phase::CheckTorque, Action::ReadTorqueEnable) if self.servos[k].hardware_error & UNSAFE_HARDWARE_ERRORS != 0 => {
                self.servos[k].cause = Some(FaultKind::ServoError);
                self.stop_for(k, StopCause::UnsafeError); // on or off: a damaged servo is not driven
            }
            (Phase::CheckTorque, Action::ReadTorqueEnable) if value != 0 => self.still_on(k),
            (Phase::CheckTorque, Action::ReadTorqueEnable) if self.servos[k].hardware_error != 0 => self.shut_down(k, now_ns),
            (Phase::CheckTorque, Action::ReadTorqueEnable) => self.torque_found_off(k, now_ns),
            (Phase::Reboot, Action::Reboot) => {
                self.servos[k].counts.reboots += 1;
                self.servos[k].enter(Phase::Rebooting { since_ns: now_ns }, now_ns + REBOOT_FIRST_POLL_NS);
            }
            (Phase::Rebooting { .. }, Action::ReadTorqueEnable) => self.servos[k].enter(Phase::Reanchor, now_ns),
            (Phase::AwaitClear { since_ns }, Action::ReadHardwareError) => {
                let s = &mut self.servos[k];
                s.hardware_error = value as u8;
                if value == 0 {
                    s.enter(Phase::Reanchor, now_ns);
                } else if now_ns.saturating_sub(since_ns) >= self.policy.lost_timeout_ns {
                    self.stop_for(k, StopCause::ErrorPersists);
                } else {
                    s.next_ns = now_ns + REBOOT_POLL_NS;
                }
            }
            (Phase::Reanchor, Action::ReadPresent) => self.servos[k].enter(Phase::Enable, now_ns),
            (Phase::Enable, Action::EnableTorque) => {
                self.servos[k].counts.reenables += 1;
                self.servos[k].enter(Phase::Verify, now_ns);
            }
            (Phase::Verify, Action::ReadTorqueEnable) if value != 0 => self.recovered(k),
            // Undone at once: the shutdown is still there (P2 until a REBOOT).
            (Phase::Verify, Action::ReadTorqueEnable) => self.servos[k].enter(Phase::Diagnose, now_ns),
            _ => {}
        }
    }

    /// Torque is on after all: a false alarm, or an error the firmware does not shut down for
    /// (a bit outside its Shutdown mask), which is counted and run on.
    fn still_on(&mut self, k: usize) {
        let s = &mut self.servos[k];
        if s.hardware_error != 0 && s.hardware_error != s.tolerated {
            s.tolerated = s.hardware_error;
            s.last_error = s.hardware_error;
            s.counts.tolerated += 1;
        }
        self.recovered(k);
    }

    /// The servo shut down with `hardware_error`: reboot where safe (module doc), else stop.
    fn shut_down(&mut self, k: usize, now_ns: u64) {
        let s = &mut self.servos[k];
        let bits = s.hardware_error;
        s.cause = Some(FaultKind::ServoError);
        let repeated_overload = bits & HW_OVERLOAD != 0
            && s.last_overload_ns.is_some_and(|t| now_ns.saturating_sub(t) < self.policy.recovery_window_ns);
        if bits & HW_OVERLOAD != 0 {
            s.last_overload_ns = Some(now_ns);
        }
        // (An unsafe error never gets here: the diagnosis stops on it, torque on or off.)
        let refusal = if self.policy.servo_error == OnServoError::Stop {
            Some(StopCause::ServoErrorPolicy)
        } else if repeated_overload {
            Some(StopCause::RepeatedOverload)
        } else {
            None
        };
        if let Some(cause) = refusal.or_else(|| self.spend_recovery(k, now_ns)) {
            return self.stop_for(k, cause);
        }
        let s = &mut self.servos[k];
        s.counts.errors += 1;
        s.last_error = bits;
        let next = if self.can_reboot { Phase::Reboot } else { Phase::AwaitClear { since_ns: now_ns } };
        s.enter(next, now_ns);
    }

    fn torque_found_off(&mut self, k: usize, now_ns: u64) {
        self.servos[k].cause = Some(FaultKind::TorqueOff);
        if self.policy.torque_off == OnTorqueOff::Stop {
            return self.stop_for(k, StopCause::TorqueOffPolicy);
        }
        if let Some(cause) = self.spend_recovery(k, now_ns) {
            return self.stop_for(k, cause);
        }
        self.servos[k].counts.torque_offs += 1;
        self.servos[k].enter(Phase::Reanchor, now_ns);
    }

    /// Takes one recovery from the joint's allowance in the window; the refusal if none is left.
    fn spend_recovery(&mut self, k: usize, now_ns: u64) -> Option<StopCause> {
        let window = self.policy.recovery_window_ns;
        let s = &mut self.servos[k];
        let mut kept = 0;
        for i in 0..s.history_len {
            if now_ns.saturating_sub(s.history[i]) < window {
                s.history[kept] = s.history[i];
                kept += 1;
            }
        }
        s.history_len = kept;
        if kept >= self.policy.max_recoveries as usize {
            return Some(StopCause::TooManyRecoveries);
        }
        s.history[kept] = now_ns;
        s.history_len += 1;
        None
    }

    fn recovered(&mut self, k: usize) {
        let s = &mut self.servos[k];
        if s.cause.is_some() && s.phase == Phase::Verify {
            s.counts.recoveries += 1;
        }
        if s.phase == Phase::Verify {
            s.tolerated = 0; // rebooted or re-enabled: whatever it ran on is gone
        }
        s.cause = None;
        s.hardware_error = 0;
        s.enter(Phase::Ok, 0);
    }

    fn stop_for(&mut self, k: usize, cause: StopCause) {
        let s = &mut self.servos[k];
        s.enter(Phase::Stopped, u64::MAX);
        self.stop.get_or_insert(StopRequest { cause, joint: Some(k), hardware_error: s.hardware_error });
    }

    /// Judges the timeouts: the bus lost since `link_lost_since` (None: up), or else a servo
    /// silent, for `lost_timeout_ns`, latches the stop request.
    pub fn judge(&mut self, now_ns: u64, link_lost_since: Option<u64>) {
        if self.stop.is_some() {
            return;
        }
        let timeout = self.policy.lost_timeout_ns;
        // While the bus is lost its own timer governs: no servo can answer on a gone port, so
        // a silence that began a few reads before the port's error is the bus's, not the servo's.
        if let Some(since) = link_lost_since {
            if now_ns.saturating_sub(since) >= timeout {
                self.stop = Some(StopRequest { cause: StopCause::BusLost, joint: None, hardware_error: 0 });
            }
            return;
        }
        let lost = self.servos.iter().position(|s| {
            s.phase != Phase::Stopped && s.unanswered_since.is_some_and(|t| now_ns.saturating_sub(t) >= timeout)
        });
        if let Some(k) = lost {
            self.stop_for(k, StopCause::ServoLost);
        }
    }

    /// After the bus came back: check every servo's torque soon (a power loss resets them too).
    pub fn check_all_soon(&mut self) {
        for s in &mut self.servos {
            s.check_due = true;
            s.unanswered_since = None;
            s.silent = false;
        }
    }

    /// The joint holds: it recovers, is silent, or the loop is to stop.
    pub fn holds(&self, k: usize) -> bool {
        self.stop.is_some() || self.servos.get(k).is_some_and(|s| s.silent || (self.acts && s.phase != Phase::Ok))
    }

    /// The joint takes part in the SyncRead of the present positions (a rebooting servo is
    /// silent by definition: asking it would only make the read wait for its deadline).
    pub fn in_sync_read(&self, k: usize) -> bool {
        self.servos.get(k).is_some_and(|s| !matches!(s.phase, Phase::Rebooting { .. } | Phase::Reboot))
    }

    /// The fault kinds of joint `k` this cycle.
    pub fn faults(&self, k: usize) -> Faults {
        let mut f = Faults::NONE;
        if let Some(s) = self.servos.get(k) {
            if let Some(cause) = s.cause {
                f.insert(cause);
            }
            // A tolerated error (torque stayed on: counted and told once) is not a fault of
            // each cycle: the joint runs, so its rows and the loop's mode say running.
            if s.alert && !(s.phase == Phase::Ok && s.tolerated != 0) {
                f.insert(FaultKind::ServoError);
            }
            if s.silent {
                f.insert(FaultKind::ServoSilent);
            }
        }
        f
    }

    pub fn stop_request(&self) -> Option<StopRequest> {
        self.stop
    }

    pub fn view(&self, k: usize) -> Option<ServoView> {
        self.servos.get(k).map(|s| ServoView {
            phase: s.phase,
            hardware_error: if s.hardware_error != 0 { s.hardware_error } else { s.tolerated },
            last_error: s.last_error,
            silent: s.silent,
            counts: s.counts,
        })
    }
}

#[cfg(test)]
#[path = "recovery_tests.rs"]
mod tests;
