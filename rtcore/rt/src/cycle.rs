//! One cycle of the loop, top to bottom, each step a named method (like ros2's
//! admittance_controller `update_and_write_commands`):
//!
//! 1. `adopt_params` / `advance_ramp`: a new parameter set applies between cycles, whole; the
//!    gains then ramp linearly from their current values over `ramp_time_s`. Linear, because
//!    the stability bound h·B/I < 1 is linear in (I, B): every point of a ramp between two
//!    accepted sets is itself stable. The position state is never touched, so nothing jumps.
//! 2. `take_force`: drain the sample ring to the newest sample (stale check, tare feed).
//! 3. `condition_force`: bias, deadband, low-pass.
//! 4. `step_joints`: torque = force[axis] × lever_arm, the admittance steps due with limited
//!    state (one per deadline: a skipped deadline is integrated too, so the model keeps the
//!    deadlines' time, caught up at most two steps a cycle so that the goal never jumps by a
//!    stall's motion; the deadline is the grid point, never the cycle's start, which a sample
//!    may trigger anywhere in the window), or a hold (velocity zero, no integration) while the
//!    force is stale.
//!    The goal is the model's angle plus the servo compensation's lead (`compensation`). The
//!    step is guarded: gains that are not usable, a state that is not finite or leaves the
//!    envelope, or a compensated goal that is not finite, hold the joint at its last good state
//!    with the goal it already has and raise `FaultKind::ModelStateInvalid` (see `fault`), so
//!    nothing but a valid state ever becomes a goal.
//!    4b. The passivity guard (`passivity`): each joint's port energy (the hand's torque times
//!    the horn's motion between reads, what it dissipated forgotten over 1 s); while the joint generates
//!    energy beyond the margin, a damping added to the model after each step.
//! 5. `write_goals`: one SyncWrite of every goal tick; the latency of a new sample is measured
//!    to the end of this write.
//! 6. `read_present`: every `sync_read_divisor` cycles, with a deadline inside the period.
//! 7. `tend_servos`: at most one transaction the servos' recovery asks for (`recovery`: a
//!    torque check, a Hardware Error Status read, a REBOOT, a re-anchor, torque on), with the
//!    same deadline; a wait (a reboot's silence) spans cycles, never one. A transaction starts
//!    only with a quarter cycle left for its reply; a recovery that a long SyncRead kept from
//!    that for [`RECOVERY_WAIT_CYCLES`] cycles gets the next cycle's bus first, its SyncRead
//!    put off a cycle.
//! 8. `publish`: telemetry records (with the model's time, each joint's fault bits and the
//!    loop's mode) and counters.
//!
//! Bus errors are counted and the cycle goes on: the next cycle writes fresh goals anyway. An
//! error that says the port itself is gone (`bus::link_gone`: the adapter unplugged) makes the
//! link *lost*: the transport reopens it off the loop thread, the cycles send nothing and hold
//! every joint (`BusLost`) until it is back, and `recovery` asks for a stop if it is not back
//! within the policy's timeout. A joint that its recovery holds (a servo shut down, silent, or
//! being brought back) holds the same way: its model frozen at its last good state.
use crate::anchor::{AnchorRefusal, ReadCheck};
use crate::bus::{BusError, BusErrorKind, JointBus, Transport};
use crate::clock::Clock;
use crate::compensation::Compensation;
use crate::passivity::PassivityGuard;
use crate::fault::{FaultKind, Faults, LoopMode};
use crate::recovery::{Action, FaultPolicy, Recovery, StopRequest};
use crate::filter::{deadband, LowPass, TareAverager};
use crate::joint::{integrate, state_in_envelope, user_torque, TickMap};
use crate::params::{JointGains, Limits, LoopParams, SensorParams};
use crate::sensor::{ForceIntake, Intake};
use crate::shared::Shared;
use crate::telemetry::{LoopStats, Record};
use plant::State;
use std::f64::consts::TAU;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// How a joint is wired: its servo ID, its force axis, its tick mapping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointWiring {
    pub id: u8,
    /// 0..6: fx, fy, fz, tx, ty, tz.
    pub axis: usize,
    pub ticks: TickMap,
}

struct JointSlot {
    wiring: JointWiring,
    state: State,
    /// The last state that passed the guard: where a fault holds the joint.
    good: State,
    /// This joint's faults this cycle.
    faults: Faults,
    limits: Limits,
    ramp_from: JointGains,
    ramp_to: JointGains,
    gains: JointGains,
    force: f64,
    torque: f64,
    present: i64,
    /// The servo answered this cycle's read of the present positions, with a trusted read.
    read_now: bool,
    /// Its position reads, each checked against what the horn could have done (`anchor`).
    reads: ReadCheck,
    compensation: Compensation,
    passivity: PassivityGuard,
}

/// Reads the start takes to confirm every joint's position (two agreeing ones suffice).
pub const START_READS: usize = 8;

/// Why the loop did not start at the servos' present positions.
#[derive(Debug)]
pub enum StartRefusal {
    /// The bus did not answer.
    Bus(BusError),
    /// A servo answered, but its position could not be trusted: the message says why.
    Position(String),
}

/// At most this many skipped deadlines are caught up (10 ms at 1 kHz); a longer stall loses
/// its time rather than move the goal by that much motion (recordings cut their trial there:
/// the model did not follow the torque over the lost time).
pub const MAX_CATCH_UP_STEPS: u64 = 10;

/// At most this many model steps in one cycle: the skipped deadlines are caught up over the
/// following cycles, the model running at twice the deadlines' pace until it is back on them.
/// Why not all at once: the goal then jumped by every lost step's motion in one cycle, the
/// servo drove the horn there as fast as it could, and the hand gripping it (read as old as
/// the stall) was given energy before any damping could act: 2.1–14.3 mJ in the stalled
/// sessions of bench/passivity.py against the guard's 2 mJ margin; spread, the goal moves
/// at most twice the model's step a cycle (docs/fidelity.md, "The catch-up, spread").
pub const CATCH_UP_STEPS_PER_CYCLE: u64 = 2;

/// A servo recovery kept waiting this many cycles in a row for lack of time gets the next
/// cycle's bus first: that cycle's SyncRead of the present positions is deferred to the cycle
/// after it (`run_cycle`).
///
/// Why: a recovery's transaction starts only with a quarter cycle left before the bus's
/// deadline (`tend_servos`), and a SyncRead that takes most of the cycle (many servos at a low
/// baud rate, a loaded host's serial port) leaves that in few cycles or none: the recovery's
/// reads came 0.4–13 s apart in the HIL glitch test, and a torque check never ran at all with
/// a SyncRead of 0.7 period (cycle_busy_bus_tests.rs). The rule itself stays (a wait cut short
/// would pass for a silent servo): it is the SyncRead that yields. Deferring one is cheap, since
/// the next cycle's read covers it: the passivity guard averages the hand's torque over the
/// cycles up to whatever read comes next, the record has no present position for that cycle (as for a
/// divisor > 1; a recording's gap is ten read periods), and the read's silence and alert
/// checks run a cycle later. Why two cycles, not one: one late cycle can be one slow SyncRead;
/// two in a row say the bus is busy. A slot is given only when the SyncWrite left a quarter
/// cycle (else the recovery could not use it, and the read would be lost for nothing), and its
/// transaction then runs, so the count starts again: the SyncRead runs in at least
/// `RECOVERY_WAIT_CYCLES` of every `RECOVERY_WAIT_CYCLES + 1` cycles, and a transaction the
/// recovery asks for runs within `RECOVERY_WAIT_CYCLES + 1` cycles of the first it could have.
pub const RECOVERY_WAIT_CYCLES: u32 = 2;

/// The fixed inputs of a controller.
pub struct ControllerParts {
    pub rate_hz: f64,
    pub joints: Vec<JointWiring>,
    pub initial: LoopParams,
    pub bus: JointBus,
    pub sync_read_divisor: u64,
    pub force_ring: rtrb::Consumer<crate::sensor::ForceSample>,
    pub params: triple_buffer::Output<LoopParams>,
    pub telemetry: rtrb::Producer<Record>,
    pub shared: Arc<Shared>,
}

pub struct Controller {
    h: f64,
    period_ns: u64,
    joints: Vec<JointSlot>,
    goals: Vec<i64>,
    ramp_progress: f64,
    ramp_time_s: f64,
    sensor: SensorParams,
    lowpass: LowPass,
    tare: TareAverager,
    bias: [f64; 6],
    bias_generation: u64,
    intake: ForceIntake,
    /// Faults of the loop as a whole this cycle (the bus's, and the sensor's raised from outside).
    loop_faults: Faults,
    /// Each servo's fault detection and recovery, and the loop's stop request.
    recovery: Recovery,
    /// CLOCK_MONOTONIC when the bus's port was lost; None while it is up.
    link_lost_since: Option<u64>,
    /// The joints held this cycle by policy (stale force).
    holding: bool,
    params: triple_buffer::Output<LoopParams>,
    bus: JointBus,
    sync_read_divisor: u64,
    /// A due read failed last cycle: try once more now (a recording's row, and the rendering
    /// error, would otherwise wait a whole divisor).
    read_retry: bool,
    /// Cycles in a row the recovery had a transaction due and no time for it
    /// ([`RECOVERY_WAIT_CYCLES`]).
    recovery_waits: u32,
    cycle: u64,
    /// The deadline the model has been integrated up to.
    model_ns: Option<u64>,
    latency_from_ns: Option<u64>,
    telemetry: rtrb::Producer<Record>,
    shared: Arc<Shared>,
}

impl Controller {
    pub fn new(parts: ControllerParts) -> Self {
        let h = 1.0 / parts.rate_hz;
        let p = &parts.initial;
        let joints = parts
            .joints
            .iter()
            .zip(&p.joints)
            .map(|(wiring, jp)| JointSlot {
                wiring: *wiring,
                state: State::default(),
                good: State::default(),
                faults: Faults::NONE,
                limits: jp.limits,
                ramp_from: jp.gains,
                ramp_to: jp.gains,
                gains: jp.gains,
                force: 0.0,
                torque: 0.0,
                present: -1,
                read_now: false,
                reads: ReadCheck::default(),
                compensation: Compensation::new(jp.servo, jp.compensation),
                passivity: PassivityGuard::new(jp.passivity),
            })
            .collect::<Vec<_>>();
        let mut lowpass = LowPass::default();
        lowpass.configure(p.sensor.lowpass_hz, h);
        parts.shared.publish_bias(&p.bias);
        joints.iter().enumerate().for_each(|(k, slot)| parts.shared.publish_limits(k, &slot.limits));
        let recovery = Recovery::new(joints.len(), FaultPolicy::default(), parts.bus.protocol() == dxl::Protocol::V2, true);
        Controller {
            h,
            period_ns: (1e9 / parts.rate_hz).round() as u64,
            goals: vec![0; joints.len()],
            joints,
            ramp_progress: 1.0,
            ramp_time_s: p.ramp_time_s,
            sensor: p.sensor,
            lowpass,
            tare: TareAverager::default(),
            bias: p.bias,
            bias_generation: p.bias_generation,
            intake: ForceIntake::new(parts.force_ring),
            loop_faults: Faults::NONE,
            recovery,
            link_lost_since: None,
            holding: false,
            params: parts.params,
            bus: parts.bus,
            sync_read_divisor: parts.sync_read_divisor,
            read_retry: false,
            recovery_waits: 0,
            cycle: 0,
            model_ns: None,
            latency_from_ns: None,
            telemetry: parts.telemetry,
            shared: parts.shared,
        }
    }

    /// The bus (which read it uses, its servos' health).
    pub fn bus(&self) -> &JointBus {
        &self.bus
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The fault policy; `acts`: the loop drives the servos' torque (it turned it on at start),
    /// so it may turn it on again after a fault (else it only detects and holds).
    pub fn set_fault_policy(&mut self, policy: FaultPolicy, acts: bool) {
        let can_reboot = self.bus.protocol() == dxl::Protocol::V2;
        self.recovery = Recovery::new(self.joints.len(), policy, can_reboot, acts);
    }

    /// The loop's request to be stopped (a fault its policy does not recover from), if any.
    pub fn stop_request(&self) -> Option<StopRequest> {
        self.recovery.stop_request()
    }

    /// Bumpless start: the model starts where each servo is, so the first goal is no jump.
    /// No single read decides where that is: each joint's position is read until two reads
    /// agree and lie within its range and limits (`anchor`), at most [`START_READS`] times.
    /// With `enable_torque`, the goals are first set to those positions and only then is
    /// torque enabled, so a servo never lunges towards a goal left over from before.
    pub fn start_at_present<C: Clock + ?Sized>(&mut self, t: &mut dyn Transport, clock: &C, deadline_ns: u64, enable_torque: bool) -> Result<(), StartRefusal> {
        // `auto`'s Fast Sync Read gets half the time to show it is answered (else Sync Read).
        let now_ns = clock.now_ns();
        self.bus.settle_read(t, now_ns + deadline_ns.saturating_sub(now_ns) / 2).map_err(StartRefusal::Bus)?;
        let speed = self.recovery.policy().horn_speed_max;
        let mut refusals: Vec<Option<AnchorRefusal>> = vec![Some(AnchorRefusal::Unconfirmed); self.joints.len()];
        for _ in 0..START_READS {
            let ticks = self.bus.read_present(t, deadline_ns).map_err(StartRefusal::Bus)?;
            let now_ns = clock.now_ns();
            for ((slot, refusal), &tick) in self.joints.iter_mut().zip(refusals.iter_mut()).zip(ticks) {
                if refusal.is_some() {
                    *refusal = slot.reads.anchor(tick, now_ns, &slot.wiring.ticks, &slot.limits, speed).err();
                    slot.present = tick;
                }
            }
            if refusals.iter().all(Option::is_none) {
                break;
            }
        }
        if let Some((slot, refusal)) = self.joints.iter().zip(&refusals).find_map(|(s, r)| r.map(|r| (s, r))) {
            return Err(StartRefusal::Position(start_refusal_message(slot, refusal)));
        }
        for (slot, goal) in self.joints.iter_mut().zip(self.goals.iter_mut()) {
            slot.state = State { theta: slot.wiring.ticks.theta_of(slot.present), omega: 0.0 };
            slot.good = slot.state;
            *goal = slot.present;
        }
        if enable_torque {
            self.bus.write_goals(t, &self.goals).map_err(StartRefusal::Bus)?;
            self.bus.set_torque(t, true).map_err(StartRefusal::Bus)?;
        }
        Ok(())
    }

    /// Marks the loop's start for the stale clock (no sample yet counts from here).
    pub fn begin(&mut self, now_ns: u64) {
        self.intake.start(now_ns);
    }

    /// The model states, in joint order (θ, ω).
    pub fn states(&self) -> impl Iterator<Item = State> + '_ {
        self.joints.iter().map(|j| j.state)
    }

    /// The current (ramped) gains, in joint order.
    pub fn gains(&self) -> impl Iterator<Item = JointGains> + '_ {
        self.joints.iter().map(|j| j.gains)
    }

    /// Runs the cycle of the grid point `grid_ns`, due at `due_ns`.
    ///
    /// The two differ when a sample starts the cycle (`trigger`): the grid point (the window's
    /// opening) is what the model's clock counts its steps against; the due time (the opening,
    /// the sample's push or the window's end) is what the wake-up's lateness and the read's
    /// deadline are measured from. On the schedule both are the deadline.
    pub fn run_cycle<C: Clock + ?Sized>(&mut self, t: &mut dyn Transport, clock: &C, grid_ns: u64, due_ns: u64) {
        let wake_ns = clock.now_ns();
        self.adopt_params();
        self.advance_ramp();
        let intake = self.take_force(wake_ns);
        let force = self.condition_force(&intake.newest.forces);
        let steps = self.steps_due(grid_ns);
        let link_up = self.keep_link(t);
        self.step_joints(&force, intake.stale, steps);
        let written = link_up && self.write_goals(t, wake_ns);
        let latency_ns = self.measure_latency(&intake, written, clock.now_ns());
        let bus_deadline = due_ns + self.period_ns - self.period_ns / 10;
        // A recovery the SyncRead has kept waiting has this cycle's bus, if its reply fits
        // (RECOVERY_WAIT_CYCLES): the SyncRead waits a cycle instead.
        let slot = written && self.recovery_waits >= RECOVERY_WAIT_CYCLES && self.time_for_reply(clock.now_ns(), bus_deadline);
        let read = written && self.read_present(t, bus_deadline, clock, slot);
        let waited = written && self.tend_servos(t, clock, bus_deadline, slot);
        self.recovery_waits = if waited { self.recovery_waits.saturating_add(1) } else { 0 };
        self.recovery.judge(clock.now_ns(), self.link_lost_since);
        self.publish(wake_ns, wake_ns.saturating_sub(due_ns), latency_ns, read);
        self.shared.stats.work.record(clock.now_ns().saturating_sub(wake_ns));
    }

    /// Whether the bus's link is up; while it is lost, takes a reopened port if one is ready
    /// (never blocks), and then has every servo's torque checked (a power loss resets them too).
    fn keep_link(&mut self, t: &mut dyn Transport) -> bool {
        if self.link_lost_since.is_none() {
            return true;
        }
        if !t.reconnect() {
            return false;
        }
        self.link_lost_since = None;
        self.shared.link.lost_since_ns.store(0, Ordering::Relaxed);
        LoopStats::add(&self.shared.link.reconnects, 1);
        self.recovery.check_all_soon();
        true
    }

    /// Counts a bus error; one that says the port is gone makes the link lost and hands the
    /// port to the transport to reopen.
    fn bus_error(&mut self, t: &mut dyn Transport, e: &BusError, kind: BusErrorKind, now_ns: u64) {
        self.shared.stats.bus_error(kind);
        if e.link_gone() && self.link_lost_since.is_none() {
            self.link_lost_since = Some(now_ns);
            self.shared.link.lost_since_ns.store(now_ns.max(1), Ordering::Relaxed);
            LoopStats::add(&self.shared.link.losses, 1);
            let errno = if let BusError::Io(io) = e { io.raw_os_error().unwrap_or(0) } else { 0 };
            self.shared.link.loss_errno.store(errno, Ordering::Relaxed);
            t.disconnect();
        }
    }

    /// Whether a transaction started at `now_ns` leaves a quarter cycle for its reply before
    /// `deadline_ns` (a wait cut short would pass for a silent servo).
    fn time_for_reply(&self, now_ns: u64, deadline_ns: u64) -> bool {
        now_ns.saturating_add(self.period_ns / 4) < deadline_ns
    }

    /// Runs the one servo transaction the recovery asks for this cycle, if any. True when it
    /// asked for one and there was no time for it (it waits: [`RECOVERY_WAIT_CYCLES`]). `slot`:
    /// this cycle's bus is the recovery's, its time checked before the SyncRead was deferred
    /// (nothing was sent since), so the transaction it asks for runs.
    fn tend_servos<C: Clock + ?Sized>(&mut self, t: &mut dyn Transport, clock: &C, deadline_ns: u64, slot: bool) -> bool {
        let now_ns = clock.now_ns();
        if !slot && !self.time_for_reply(now_ns, deadline_ns) {
            return self.recovery.wants_action(now_ns); // next cycle
        }
        let Some((k, action)) = self.recovery.next_action(now_ns) else { return false };
        let bus = &mut self.bus;
        let result = match action {
            Action::ReadHardwareError => bus.read_hardware_error(t, k, deadline_ns).map(i64::from),
            Action::ReadTorqueEnable => bus.read_torque_enable(t, k, deadline_ns).map(i64::from),
            Action::Reboot => bus.reboot(t, k, deadline_ns).map(|()| 0),
            Action::ReadPresent => bus.read_present_one(t, k, deadline_ns),
            Action::EnableTorque => bus.write_torque(t, k, true, deadline_ns).map(|()| 0),
        };
        let now_ns = clock.now_ns();
        let alert = self.bus.health()[k].alert(self.bus.protocol());
        let answered = !matches!(&result, Err(e) if e.unanswered());
        self.recovery.observe(k, answered, alert, now_ns);
        let mut result = result.map_err(|e| self.bus_error(t, &e, e.read_kind(), now_ns));
        if let (Action::ReadPresent, Ok(tick)) = (action, result) {
            // Not confirmed yet (or not where torque may go on): read again, torque stays off.
            result = self.reanchor(k, tick, now_ns);
        }
        self.recovery.on_result(k, action, result, now_ns);
        false
    }

    /// The model of joint `k` starts again where its horn is, once a read confirms where that
    /// is (`anchor`): θ = the present tick's angle at rest, the compensation's lead dropped, so
    /// the goal the next SyncWrite carries is the present position itself (torque goes on only
    /// after that write: no jump). `Err` while the read is not confirmed: the recovery reads again.
    fn reanchor(&mut self, k: usize, tick: i64, now_ns: u64) -> Result<i64, ()> {
        let speed = self.recovery.policy().horn_speed_max;
        let slot = &mut self.joints[k];
        match slot.reads.anchor(tick, now_ns, &slot.wiring.ticks, &slot.limits, speed) {
            Ok(tick) => {
                slot.state = State { theta: slot.wiring.ticks.theta_of(tick), omega: 0.0 };
                slot.good = slot.state;
                slot.present = tick;
                slot.compensation.reanchor();
                self.goals[k] = tick;
                Ok(tick)
            }
            Err(refusal) => {
                // The first read of an anchoring has nothing to agree with yet: not a glitch.
                if refusal != AnchorRefusal::Unconfirmed {
                    slot.faults.insert(FaultKind::PositionGlitch);
                }
                Err(())
            }
        }
    }

    fn adopt_params(&mut self) {
        if !self.params.updated() {
            return;
        }
        let p = self.params.read();
        for (k, (slot, jp)) in self.joints.iter_mut().zip(&p.joints).enumerate() {
            slot.ramp_from = slot.gains;
            slot.ramp_to = jp.gains;
            slot.limits = jp.limits;
            self.shared.publish_limits(k, &slot.limits);
            slot.compensation.retarget(jp.servo, jp.compensation);
            slot.passivity.retarget(jp.passivity);
        }
        self.ramp_progress = 0.0;
        self.ramp_time_s = p.ramp_time_s;
        self.sensor = p.sensor;
        self.lowpass.configure(p.sensor.lowpass_hz, self.h);
        if p.bias_generation != self.bias_generation {
            self.bias_generation = p.bias_generation;
            self.bias = p.bias;
            self.shared.publish_bias(&self.bias);
        }
    }

    fn advance_ramp(&mut self) {
        if self.ramp_progress >= 1.0 {
            return;
        }
        self.ramp_progress = if self.ramp_time_s > 0.0 {
            (self.ramp_progress + self.h / self.ramp_time_s).min(1.0)
        } else {
            1.0
        };
        for slot in &mut self.joints {
            slot.gains = slot.ramp_from.lerp(&slot.ramp_to, self.ramp_progress);
        }
    }

    fn take_force(&mut self, now_ns: u64) -> Intake {
        let requested = self.shared.tare_request.swap(0, Ordering::Relaxed);
        if requested > 0 {
            self.tare.request(requested);
        }
        let timeout_ns = (self.sensor.stale_timeout_ms * 1e6) as u64;
        let (intake, tared) = self.intake.take(now_ns, timeout_ns, &mut self.tare);
        if let Some(bias) = tared {
            self.bias = bias;
            self.shared.publish_bias(&bias);
        }
        LoopStats::add(&self.shared.stats.sensor_samples, intake.drained);
        if intake.became_stale {
            LoopStats::add(&self.shared.stats.sensor_stale_events, 1);
        }
        intake
    }

    fn condition_force(&mut self, raw: &[f64; 6]) -> [f64; 6] {
        let mut f = [0.0; 6];
        for (k, v) in f.iter_mut().enumerate() {
            *v = deadband(raw[k] - self.bias[k], self.sensor.deadband);
        }
        self.lowpass.apply(&f)
    }

    /// Model steps due at this deadline: towards the model's own time (whole steps of one
    /// period) nearest to the deadline, so the model keeps the deadlines' time through an
    /// overrun (recordings and `identify` rely on it), but at most
    /// [`CATCH_UP_STEPS_PER_CYCLE`] a cycle: after a stall the model catches up over the next
    /// cycles (its time, and the records' `deadline_ns`, trail the deadlines until then).
    /// Counted against the model's time, not the previous deadline, so a grid that shifts or
    /// stretches by a bounded amount (a phase-locked clock) keeps the two within half a period
    /// instead of drifting apart; a grid that moved back gives a cycle of no step. A stall that
    /// leaves more than [`MAX_CATCH_UP_STEPS`] due loses its time (the model's time restarts at
    /// this deadline, after this cycle's steps).
    fn steps_due(&mut self, deadline_ns: u64) -> u64 {
        let Some(model_ns) = self.model_ns else {
            self.model_ns = Some(deadline_ns);
            return 1;
        };
        let due = deadline_ns.saturating_sub(model_ns).saturating_add(self.period_ns / 2) / self.period_ns;
        let steps = due.min(CATCH_UP_STEPS_PER_CYCLE);
        self.model_ns = Some(if due > MAX_CATCH_UP_STEPS { deadline_ns } else { model_ns + steps * self.period_ns });
        steps
    }

    fn step_joints(&mut self, force: &[f64; 6], stale: bool, steps: u64) {
        self.holding = stale;
        let h = self.h;
        let link_lost = self.link_lost_since.is_some();
        for (k, (slot, goal)) in self.joints.iter_mut().zip(self.goals.iter_mut()).enumerate() {
            slot.force = force[slot.wiring.axis];
            slot.torque = user_torque(force, slot.wiring.axis, &slot.gains);
            slot.faults = Faults::NONE;
            // The force is stale, the bus is gone, or the servo is being recovered: hold.
            let hold = stale || link_lost || self.recovery.holds(k);
            // 4b. The passivity guard sees the last read of the horn and this cycle's torque.
            let horn = slot.read_now.then(|| slot.wiring.ticks.theta_of(slot.present));
            slot.passivity.observe(horn, slot.torque, &slot.state, &slot.gains, hold, h);
            let mut alpha = 0.0;
            if hold {
                slot.state.omega = 0.0;
            } else {
                for _ in 0..steps {
                    alpha = integrate(&mut slot.state, &slot.gains, &slot.limits, slot.torque, h);
                    // Added to α: the compensation's inertial lead must see the damped model's
                    // acceleration, not the τ/I of the undamped one that makes a light joint oscillate.
                    alpha += slot.passivity.damp(&mut slot.state, slot.gains.inertia, h);
                }
            }
            slot.compensation.advance(h, self.ramp_time_s);
            // No step (a hold, or a grid that moved back): the lead stays, so the goal does.
            match state_usable(slot).then(|| compensated_goal(slot, alpha, hold || steps == 0, h)).flatten() {
                Some(tick) => {
                    slot.good = slot.state;
                    *goal = tick;
                }
                None => hold_at_good(slot), // and the goal it already has
            }
        }
    }

    fn write_goals(&mut self, t: &mut dyn Transport, now_ns: u64) -> bool {
        match self.bus.write_goals(t, &self.goals) {
            Ok(()) => true,
            Err(e) => {
                self.bus_error(t, &e, BusErrorKind::Write, now_ns);
                false
            }
        }
    }

    /// The latency of the sample that this write used first; −1 when there is none.
    fn measure_latency(&mut self, intake: &Intake, written: bool, now_ns: u64) -> i64 {
        if intake.new_arrival {
            self.latency_from_ns = Some(intake.newest.t_ns);
        }
        if intake.stale {
            self.latency_from_ns = None;
        }
        match (written, self.latency_from_ns) {
            (true, Some(arrival)) => {
                self.latency_from_ns = None;
                let latency = now_ns.saturating_sub(arrival);
                self.shared.stats.latency.record(latency);
                latency as i64
            }
            _ => -1,
        }
    }

    /// Reads the present positions when due, or once more the cycle after a due read failed;
    /// true if this cycle read any. A silent servo so costs at most two reads per divisor, and
    /// the others' positions still arrive. Every answer (or its absence), with its alert bit,
    /// goes to the servos' recovery. `defer`: the recovery has this cycle's bus, and a read due
    /// now is made the next cycle instead ([`RECOVERY_WAIT_CYCLES`]).
    fn read_present<C: Clock + ?Sized>(&mut self, t: &mut dyn Transport, deadline_ns: u64, clock: &C, defer: bool) -> bool {
        self.joints.iter_mut().for_each(|slot| slot.read_now = false);
        let due = self.sync_read_divisor > 0 && self.cycle.is_multiple_of(self.sync_read_divisor);
        let retry = std::mem::take(&mut self.read_retry);
        if !due && !retry {
            return false;
        }
        if defer {
            self.read_retry = true;
            LoopStats::add(&self.shared.stats.reads_deferred, 1);
            return false;
        }
        self.read_retry = due && self.sync_read_divisor > 1;
        let recovery = &self.recovery;
        let result = self.bus.read_present_of(t, deadline_ns, |k| recovery.in_sync_read(k));
        let now_ns = clock.now_ns();
        let protocol = self.bus.protocol();
        let speed = self.recovery.policy().horn_speed_max;
        let mut any = false;
        for (k, slot) in self.joints.iter_mut().enumerate() {
            if !self.recovery.in_sync_read(k) {
                continue;
            }
            let answered = self.bus.answered()[k];
            self.recovery.observe(k, answered, self.bus.health()[k].alert(protocol), now_ns);
            if !answered {
                continue;
            }
            // A jump no horn can make is marked and kept out of the record (`anchor`).
            if slot.reads.running(self.bus.present()[k], now_ns, &slot.wiring.ticks, speed) {
                slot.present = self.bus.present()[k];
                slot.read_now = true;
                if watch_compensation(slot, self.h * self.sync_read_divisor.max(1) as f64) {
                    LoopStats::add(&self.shared.stats.compensation_fallbacks, 1);
                }
            } else {
                slot.faults.insert(FaultKind::PositionGlitch);
            }
            any = true;
        }
        match result {
            Ok(()) => {
                if any {
                    LoopStats::add(&self.shared.stats.sync_reads, 1);
                }
                self.read_retry = false;
            }
            Err(e) => self.bus_error(t, &e, e.read_kind(), now_ns),
        }
        any
    }

    fn publish(&mut self, wake_ns: u64, period_error_ns: u64, latency_ns: i64, read: bool) {
        self.loop_faults = self.shared.external_faults.get();
        if self.link_lost_since.is_some() {
            self.loop_faults.insert(FaultKind::BusLost);
        }
        for (k, slot) in self.joints.iter_mut().enumerate() {
            slot.faults = slot.faults.union(self.recovery.faults(k));
            if let (Some(view), Some(shared)) = (self.recovery.view(k), self.shared.servos.get(k)) {
                shared.publish(&view);
            }
            if let Some(shared) = self.shared.passivity.get(k) {
                shared.publish(&slot.passivity.view());
            }
        }
        self.shared.stop_request.store(StopRequest::encode(self.recovery.stop_request()), Ordering::Relaxed);
        let stats = &self.shared.stats;
        let active = self.joints.iter().fold(self.loop_faults, |all, slot| all.union(slot.faults));
        let mode = LoopMode::of(active, self.holding);
        stats.faults.record(active, mode);
        for (slot, &goal) in self.joints.iter().zip(&self.goals) {
            let guard = slot.passivity.view();
            let record = Record {
                cycle: self.cycle,
                t_ns: wake_ns,
                deadline_ns: self.model_ns.unwrap_or(wake_ns),
                id: slot.wiring.id as i64,
                force: slot.force,
                torque: slot.torque,
                theta: slot.state.theta,
                omega: slot.state.omega,
                goal_tick: goal,
                present_tick: if read && slot.read_now { slot.present } else { -1 },
                period_error_ns: period_error_ns as i64,
                latency_ns,
                fault: slot.faults.union(self.loop_faults).bits(),
                mode: mode as i64,
                passivity_energy: guard.balance,
                passivity_damping: guard.damping,
            };
            if self.telemetry.push(record).is_err() {
                LoopStats::add(&stats.telemetry_drops, 1);
            }
        }
        stats.period.record(period_error_ns);
        self.cycle += 1;
        LoopStats::add(&stats.cycles, 1);
    }

    /// The stop policy's last traffic: Torque Enable = 0 on every joint (a bus that is lost
    /// first gets one chance to have come back).
    pub fn torque_off(&mut self, t: &mut dyn Transport) -> Result<(), BusError> {
        if self.link_lost_since.is_some() && !t.reconnect() {
            return Err(BusError::Io(std::io::ErrorKind::NotConnected.into()));
        }
        self.bus.set_torque(t, false)
    }
}

/// The start's one line for a joint whose position it could not trust.
fn start_refusal_message(slot: &JointSlot, refusal: AnchorRefusal) -> String {
    let id = slot.wiring.id;
    let Limits { position_min, position_max, .. } = slot.limits;
    match refusal {
        AnchorRefusal::OutsideLimits { theta } => format!(
            "servo {id} rests at {theta:.3} rad, outside its position limits [{position_min:.3}, {position_max:.3}] rad: \
             move the joint within them by hand (torque stays off), or widen the limits"
        ),
        AnchorRefusal::OutOfRange { tick } => format!(
            "servo {id} reports position tick {tick}, outside its range {}..={}: check its operating mode and encoder",
            slot.wiring.ticks.tick_min, slot.wiring.ticks.tick_max
        ),
        AnchorRefusal::Unconfirmed | AnchorRefusal::Disagrees | AnchorRefusal::Jump { .. } => format!(
            "servo {id}'s position reads did not agree in {START_READS} reads (the last: tick {}): a loose encoder or \
             bus noise; torque stays off",
            slot.present
        ),
    }
}

/// The state guard's test, after a joint's step: gains the loop can integrate with and a state
/// that is finite and inside the envelope.
fn state_usable(slot: &JointSlot) -> bool {
    slot.gains.usable() && state_in_envelope(&slot.state, &slot.wiring.ticks)
}

/// The goal tick of a usable state: the model's angle plus the compensation's lead, which may
/// not carry the goal past a position limit (a state already outside a narrowed range stays
/// where it is, as the integrator lets it). None when the led angle is not finite: it would
/// reach the bus as tick 0, a jump across the range.
fn compensated_goal(slot: &mut JointSlot, alpha: f64, hold: bool, h: f64) -> Option<i64> {
    let State { theta, omega } = slot.state;
    // A model brought to rest within one step (a stick, a position limit) decelerated by ω/h:
    // the reference stops, and the servo is to hold, not to brake that hard.
    let alpha = if omega == 0.0 { 0.0 } else { alpha };
    slot.compensation.set_virtual_inertia(slot.gains.inertia);
    let led = slot.compensation.goal(theta, omega, alpha, slot.torque, hold, h);
    if !led.is_finite() {
        return None; // checked before the limits: max/min would turn a NaN into a bound
    }
    // min/max, not clamp: clamp panics on crossed or NaN bounds, and the RT thread never panics.
    Some(slot.wiring.ticks.goal_tick(led.max(slot.limits.position_min.min(theta)).min(slot.limits.position_max.max(theta))))
}

/// Hands a trusted read of the horn to the compensation's watch (`compensation`): true when the
/// compensation made the horn worse than none would, and is being blended out.
fn watch_compensation(slot: &mut JointSlot, dt: f64) -> bool {
    let ticks = &slot.wiring.ticks;
    let tick = (TAU / ticks.ticks_per_rev).abs();
    slot.compensation.watch(ticks.theta_of(slot.present) - slot.state.theta, dt, tick)
}

/// The guard's policy when a state or its goal is not usable: the joint holds at its last good
/// state (velocity zero; its goal is left as it is) and the fault is raised for this cycle; the
/// next cycle tries again from that good state.
fn hold_at_good(slot: &mut JointSlot) {
    slot.faults.insert(FaultKind::ModelStateInvalid);
    slot.state = State { theta: slot.good.theta, omega: 0.0 };
    slot.compensation.hold();
    if !slot.torque.is_finite() {
        slot.torque = 0.0; // the record shows the hand's torque, unless the gains made it NaN
    }
}

#[cfg(test)]
#[path = "cycle_tests.rs"]
pub(crate) mod tests;

#[cfg(test)]
#[path = "cycle_fault_tests.rs"]
mod fault_tests;

#[cfg(test)]
#[path = "cycle_passivity_tests.rs"]
mod passivity_tests;

#[cfg(test)]
#[path = "cycle_busy_bus_tests.rs"]
mod busy_bus_tests;
