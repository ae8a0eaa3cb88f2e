//! The embedded bench in model time: the real loop cycle (`rt::cycle::Controller`) and the
//! simulated servos (this crate's bus, its horns moved by the rtcore plant) stepped in lockstep
//! on one simulated clock, with the gripping hand and the sensor between it and the horn.
//!
//! Why: on a shared machine the wall-clock bench's figures depend on the load (the same
//! session gave 2.75–145 mJ of generated energy from run to run), so a controller change cannot
//! be judged by them. Here nothing reads the wall clock: a cycle's deadline, the wire's reply
//! times, the physics' substeps and the sensor's samples all count on the simulated clock, so
//! a run is a pure function of its inputs: two runs give the same records bit for bit, whatever
//! the load. The physics is the same code the embedded bench runs (`wire::Answerer` brings the
//! servos up to each instruction's arrival, as the in-process link does); only the clock
//! differs. What it leaves out, by design: the scheduler's lateness (overruns, late reads), which
//! the wall-clock bench keeps measuring end to end.
//!
//! Each cycle at grid point t: the hand's muscle torque τ(t) is applied to its servo, the
//! physics runs up to t, the sensor's sample (what the hand transmits, through the sensor's
//! counts and seeded noise: `daq::ForceModel`) is pushed with time stamp t, and the loop runs its
//! cycle with its deadline at t (the sensor's arrival trigger puts it there on the real bench).
use std::collections::VecDeque;
use std::io;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};

use rt::bus::{JointBus, Transport};
use rt::clock::{Clock, SharedClock};
use rt::config::LoopConfig;
use rt::cycle::{Controller, ControllerParts};
use rt::sensor::ForceSample;
use rt::shared::Shared as LoopShared;
use rt::telemetry::Record;

use crate::daq::{ForceModel, Gaussian, HandProfile};
use crate::server::{lock, BusConfig, Shared};
use crate::wire::Answerer;

/// ns: the simulated clock's origin (any value well above 0: deadlines subtract from it).
const EPOCH_NS: u64 = 1_000_000_000;

/// The loop's wire to the simulated servos on the simulated clock: a reply is readable once the
/// clock reaches its due time, and waiting for it moves the clock there.
pub struct LockstepLink {
    shared: Arc<Mutex<Shared>>,
    answerer: Answerer,
    output: VecDeque<u8>,
    clock: SharedClock, // the simulated time line, shared by the loop and the link (a reply's wait moves it on)
}

impl Transport for LockstepLink {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        let now = self.clock.now_ns();
        self.answerer.receive(now, bytes, &mut lock(&self.shared));
        Ok(())
    }

    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> io::Result<usize> {
        loop {
            let now = self.clock.now_ns();
            while let Some((_, bytes)) = self.answerer.pop_due(now) {
                self.output.extend(bytes);
            }
            if !self.output.is_empty() {
                let n = buf.len().min(self.output.len());
                for (slot, byte) in buf.iter_mut().zip(self.output.drain(..n)) {
                    *slot = byte;
                }
                return Ok(n);
            }
            match self.answerer.next_due_ns() {
                Some(due) if due <= deadline_ns => self.clock.advance_to(due),
                _ => {
                    self.clock.advance_to(deadline_ns);
                    return Ok(0);
                }
            }
        }
    }

    fn kind(&self) -> &'static str {
        "lockstep"
    }
}

/// The hand and the sensor of a lockstep run.
pub struct LockstepHand {
    /// The muscle's torque over time (from `delay_s` after the start), N·m.
    pub profile: HandProfile,
    pub delay_s: f64,
    /// The servo the hand grips (its `Hand`, if any, set on the bus beforehand).
    pub servo: u8,
    /// What the sensor reports of the transmitted torque (lever arm, axis, counts, noise).
    pub sensor: ForceModel,
    pub seed: u64,
    /// The loop's stalls, seeded (a shared machine's: the scheduler runs the loop late).
    pub stalls: Stalls,
}

/// A loaded machine's effect on the loop, made repeatable: at each grid point a stall begins with
/// `probability`, lasting 1..=`max_cycles` cycles (uniform, from the run's seed), during which the
/// loop does not run while the servos, the hand and the sensor go on; the cycles after it catch
/// up as the real loop does (`cycle::steps_due`: the model integrates the lost steps, two a cycle,
/// and the first horn read after it is as old as the stall). The wall-clock bench at load 1–2
/// counted overruns in 5–25 % of its cycles.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stalls {
    pub probability: f64,
    pub max_cycles: u32,
}

/// What a run gives: every telemetry record, and the loop's counters.
pub struct LockstepRun {
    pub records: Vec<Record>,
    pub cycles: u64,
    /// Stalls the run injected (`Stalls`).
    pub overruns: u64,
}

/// Runs the loop of `config` on the servos of `shared` for `seconds` of model time. The bus's
/// own thread must not run (nothing but this run may move its physics). Err: the configuration,
/// or the start's refusal, in one line.
pub fn run(config: &LoopConfig, shared: Arc<Mutex<Shared>>, bus: BusConfig, hand: &LockstepHand, seconds: f64) -> Result<LockstepRun, String> {
    config.validate()?;
    hand.sensor.validate()?;
    let stalls = hand.stalls;
    if !((0.0..=0.5).contains(&stalls.probability) && stalls.max_cycles <= 100) {
        return Err(format!("stalls: a probability within 0..=0.5 and at most 100 cycles, not {stalls:?}"));
    }
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 3600.0) {
        return Err(format!("a lockstep run lasts 0 to 3600 s of model time, not {seconds}"));
    }
    let clock = SharedClock::default();
    clock.advance_to(EPOCH_NS);
    let protocol = lock(&shared).bus.protocol();
    if protocol != config.protocol {
        return Err("the simulated servos and the loop's configuration use different protocols".into());
    }
    lock(&shared).physics.start(EPOCH_NS);
    let mut link = LockstepLink { shared: shared.clone(), answerer: Answerer::new(protocol, bus, EPOCH_NS), output: VecDeque::new(), clock: clock.clone() };
    let (mut force, force_ring) = rtrb::RingBuffer::new(config.force_capacity);
    let (telemetry_tx, mut telemetry) = rtrb::RingBuffer::new(config.telemetry_capacity);
    let initial = config.initial_params();
    let (_params_in, params_out) = triple_buffer::triple_buffer(&initial);
    let loop_shared = Arc::new(LoopShared::for_joints(config.joints.len()));
    let mut joint_bus = JointBus::new(config.protocol, config.registers(), &config.ids());
    joint_bus.choose_read(config.bus_read, config.models_have_fast_sync_read());
    let mut controller = Controller::new(ControllerParts {
        rate_hz: config.rate_hz,
        joints: config.wiring(),
        initial,
        bus: joint_bus,
        sync_read_divisor: config.sync_read_divisor,
        force_ring,
        params: params_out,
        telemetry: telemetry_tx,
        shared: loop_shared.clone(),
    });
    controller.set_fault_policy(config.faults, config.torque_on_start);
    let start_deadline = EPOCH_NS + (config.start_timeout_ms * 1e6) as u64;
    controller
        .start_at_present(&mut link, &clock, start_deadline, config.torque_on_start)
        .map_err(|e| format!("the loop did not start: {e:?}"))?;
    let period = controller.period_ns();
    // The first cycle on the grid after the start's transactions.
    let first = (clock.now_ns() / period + 1) * period;
    controller.begin(first);
    let mut noise = Gaussian::new(hand.seed);
    let mut scheduler = Gaussian::new(hand.seed ^ 0x5EED_57A1);
    let mut stalled = 0u32;
    let mut overruns = 0;
    let mut records = Vec::new();
    let n = (seconds * config.rate_hz).round() as u64;
    for k in 0..n {
        let grid = first + k * period;
        clock.advance_to(grid);
        let t = (grid - first) as f64 * 1e-9 - hand.delay_s;
        let sensed = hand_at(&shared, hand, if t >= 0.0 { hand.profile.at(t) } else { 0.0 }, grid);
        let forces = hand.sensor.forces(sensed, &mut noise);
        // A full ring is the loop's to count (never here: one sample a cycle).
        let _ = force.push(ForceSample { t_ns: grid, forces });
        if stalled == 0 && stalls.max_cycles > 0 && scheduler.uniform() < stalls.probability {
            stalled = 1 + (scheduler.uniform() * f64::from(stalls.max_cycles)) as u32 % stalls.max_cycles;
            overruns += 1;
        }
        if stalled > 0 {
            stalled -= 1;
            continue; // the loop is not running: the physics and the sensor go on
        }
        controller.run_cycle(&mut link, &clock, grid, grid);
        while let Ok(r) = telemetry.pop() {
            records.push(r);
        }
    }
    let stats = &loop_shared.stats;
    Ok(LockstepRun { records, cycles: stats.cycles.load(Ordering::Relaxed), overruns })
}

/// Applies the muscle's torque to the hand's servo, runs the physics up to `now_ns`; what the
/// sensor between hand and horn reads (the torque, N·m).
fn hand_at(shared: &Mutex<Shared>, hand: &LockstepHand, muscle: f64, now_ns: u64) -> f64 {
    let mut s = lock(shared);
    s.advance_physics(now_ns);
    match s.bus.servo_mut(hand.servo) {
        Some(servo) => {
            servo.set_external_torque(muscle);
            servo.snapshot().hand_torque
        }
        None => muscle,
    }
}

#[cfg(test)]
#[path = "lockstep_tests.rs"]
mod tests;
