//! The tick logic against the in-memory bus and the fake clock: what a cycle writes, when it
//! holds, how parameter sets arrive, and how the pacing counts overruns.
use super::*;
use crate::bus::memory::MemoryTransport;
use crate::bus::Registers;
use crate::clock::fake::FakeClock;
use crate::fault::LoopMode;
use crate::params::tests::params;
use crate::sensor::ForceSample;
use dxl::Protocol;

pub(crate) const RATE: f64 = 1000.0;
pub(crate) const PERIOD: u64 = 1_000_000;

pub(crate) struct Rig {
    pub(crate) ctl: Controller,
    pub(crate) bus: MemoryTransport,
    pub(crate) clock: FakeClock,
    pub(crate) force: rtrb::Producer<ForceSample>,
    pub(crate) params: triple_buffer::Input<LoopParams>,
    pub(crate) telemetry: rtrb::Consumer<Record>,
    pub(crate) shared: Arc<Shared>,
}

pub(crate) fn rig(initial: LoopParams, present: &[(u8, i64)]) -> Rig {
    let ids: Vec<u8> = present.iter().map(|p| p.0).collect();
    let regs = Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 };
    let (force, force_ring) = rtrb::RingBuffer::new(64);
    let (telemetry_tx, telemetry) = rtrb::RingBuffer::new(1 << 16);
    let (params_in, params_out) = triple_buffer::triple_buffer(&initial);
    let shared = Arc::new(Shared::for_joints(ids.len()));
    let ticks = TickMap { zero_tick: 2048, direction: 1, ticks_per_rev: 4096.0, tick_min: 0, tick_max: 4095 };
    let ctl = Controller::new(ControllerParts {
        rate_hz: RATE,
        joints: ids.iter().map(|&id| JointWiring { id, axis: 0, ticks }).collect(),
        initial,
        bus: JointBus::new(Protocol::V2, regs, &ids),
        sync_read_divisor: 0,
        force_ring,
        params: params_out,
        telemetry: telemetry_tx,
        shared: shared.clone(),
    });
    // These tests do not turn torque on: the loop only detects servo faults (cycle_fault_tests
    // drives the recovery).
    let mut ctl = ctl;
    ctl.set_fault_policy(crate::recovery::FaultPolicy::default(), false);
    let bus = MemoryTransport::new(true, present);
    Rig { ctl, bus, clock: FakeClock::new(1_000_000_000, 0), force, params: params_in, telemetry, shared }
}

/// A rig whose controller already read the present positions and started its stale clock.
pub(crate) fn started(initial: LoopParams, present: &[(u8, i64)]) -> Rig {
    let mut r = rig(initial, present);
    let mut bus = r.bus.clone();
    r.ctl.start_at_present(&mut bus, &r.clock, 0, false).unwrap();
    r.ctl.begin(r.clock.now_ns());
    r
}

impl Rig {
    /// Pushes a fresh sample with `fx` and runs one cycle on the grid.
    pub(crate) fn cycle_with(&mut self, fx: Option<f64>) -> Record {
        let deadline = self.clock.now_ns() + PERIOD;
        let mut clock = self.clock.clone();
        clock.sleep_until(deadline);
        if let Some(fx) = fx {
            self.force.push(ForceSample { t_ns: self.clock.now_ns(), forces: [fx, 0.0, 0.0, 0.0, 0.0, 0.0] }).unwrap();
        }
        let mut bus = self.bus.clone();
        self.ctl.run_cycle(&mut bus, &self.clock, deadline, deadline);
        self.telemetry.pop().unwrap()
    }

    fn last_goal_written(&self) -> i64 {
        self.last_goal_written_in(&self.bus.written().pop().unwrap())
    }

    fn last_goal_written_in(&self, packet: &[u8]) -> i64 {
        // FF FF FD 00 FE len len 83 addr addr size size id d0 d1 d2 d3 crc crc
        i32::from_le_bytes([packet[13], packet[14], packet[15], packet[16]]) as i64
    }
}

pub(crate) fn free_joint() -> LoopParams {
    let mut p = params(1);
    p.joints[0].gains = JointGains { inertia: 0.02, damping: 0.0, coulomb: 0.0, lever_arm: 0.1 };
    p.joints[0].limits = Limits { position_min: -1e3, position_max: 1e3, velocity_max: 1e3, acceleration_max: 1e6 };
    p
}

#[test]
fn a_constant_force_gives_the_goal_ticks_of_the_model() {
    let mut r = started(free_joint(), &[(1, 2048)]);
    let (fx, h, inertia) = (2.0, 1.0 / RATE, 0.02);
    let a = fx * 0.1 / inertia;
    for n in 1..=300u64 {
        let rec = r.cycle_with(Some(fx));
        // Semi-implicit Euler from rest: θ_n = a·h²·n(n+1)/2.
        let theta = a * h * h * (n * (n + 1)) as f64 / 2.0;
        assert!((rec.theta - theta).abs() < 1e-9, "cycle {n}: {} vs {theta}", rec.theta);
        let tick = 2048 + (theta * 4096.0 / std::f64::consts::TAU).round() as i64;
        assert_eq!(rec.goal_tick, tick);
        assert_eq!(r.last_goal_written(), tick);
        assert_eq!(rec.torque, fx * 0.1);
        assert!(rec.latency_ns >= 0);
    }
    assert_eq!(r.bus.written().len(), 302, "two SyncReads at start (two agreeing reads), then one SyncWrite per cycle");
}

#[test]
fn the_loop_starts_where_the_servo_is() {
    let mut r = started(free_joint(), &[(1, 3000)]);
    let rec = r.cycle_with(Some(0.0));
    assert_eq!(rec.goal_tick, 3000);
    let mut enabling = rig(free_joint(), &[(1, 1234)]);
    let mut bus = enabling.bus.clone();
    enabling.ctl.start_at_present(&mut bus, &enabling.clock, 0, true).unwrap();
    let written = enabling.bus.written();
    assert_eq!(written.len(), 4, "two agreeing reads, goal = present, then torque on");
    assert_eq!(enabling.last_goal_written_in(&written[2]), 1234);
    assert_eq!(&written[3][8..13], &[64, 0, 1, 0, 1], "Torque Enable = 1 for id 1");
}

#[test]
fn stale_force_holds_position_and_counts_one_event() {
    let mut r = rig(free_joint(), &[(1, 2048)]);
    r.ctl.begin(r.clock.now_ns());
    for _ in 0..20 {
        r.cycle_with(Some(5.0));
    }
    let moving = r.cycle_with(Some(5.0));
    assert!(moving.omega > 0.0);
    // No more samples: 50 ms later the data is stale.
    let mut held = Vec::new();
    for _ in 0..100 {
        held.push(r.cycle_with(None));
    }
    let first_hold = held.iter().position(|rec| rec.omega == 0.0).unwrap();
    assert!(first_hold >= 49, "held too early: {first_hold}");
    assert!(held.iter().enumerate().all(|(k, rec)| (rec.mode == LoopMode::Holding as i64) == (k >= first_hold)));
    let hold_theta = held[first_hold].theta;
    assert!(held[first_hold..].iter().all(|rec| rec.theta == hold_theta && rec.omega == 0.0));
    assert_eq!(r.shared.stats.sensor_stale_events.load(Ordering::Relaxed), 1);
    // A fresh sample releases the hold; the model starts again from rest, not from old velocity.
    let released = r.cycle_with(Some(5.0));
    assert!(released.theta > hold_theta && released.omega < moving.omega);
}

#[test]
fn a_parameter_set_ramps_without_a_jump() {
    let mut start = free_joint();
    start.joints[0].gains.damping = 5.0;
    start.ramp_time_s = 0.1;
    let mut r = rig(start.clone(), &[(1, 2048)]);
    r.ctl.begin(r.clock.now_ns());
    for _ in 0..50 {
        r.cycle_with(Some(3.0));
    }
    let mut next = start.clone();
    next.joints[0].gains.damping = 0.0;
    next.joints[0].gains.inertia = 0.2;
    r.params.write(next);
    let mut previous = r.cycle_with(Some(3.0));
    let mut inertias = Vec::new();
    for _ in 0..150 {
        let rec = r.cycle_with(Some(3.0));
        assert!((rec.theta - previous.theta).abs() < 1e-3, "θ jumped");
        previous = rec;
        inertias.push(r.ctl.gains().next().unwrap().inertia);
    }
    // Linear over 100 cycles: equal steps, then the target exactly.
    let steps: Vec<f64> = inertias.windows(2).take(90).map(|w| w[1] - w[0]).collect();
    assert!(steps.iter().all(|s| (s - 0.0018).abs() < 1e-9), "{steps:?}");
    assert_eq!(*inertias.last().unwrap(), 0.2);
}

/// A live set's limits, narrowed and widened, position and velocity: the loop adopts them at
/// the next cycle (the goal never leaves the adopted range; the speed never exceeds the adopted
/// maximum), and what it adopted is what `Shared` (so `params()`) reports.
#[test]
fn live_limits_are_adopted_narrowed_and_widened_and_reported() {
    let tick = |theta: f64| 2048 + (theta * 4096.0 / std::f64::consts::TAU).round() as i64;
    let mut start = free_joint();
    start.ramp_time_s = 0.0;
    let mut r = started(start.clone(), &[(1, 2048)]);
    let push = 4.0; // N: 0.4 N·m on 0.02 kg·m², 20 rad/s²
    let run = |r: &mut Rig, set: Option<LoopParams>, cycles: usize| {
        if let Some(set) = set {
            r.params.write(set);
        }
        (0..cycles).map(|_| r.cycle_with(Some(push))).collect::<Vec<Record>>()
    };
    run(&mut r, None, 100); // moving: ω ≈ 2 rad/s, θ ≈ 0.1
    let mut narrow = start.clone();
    narrow.joints[0].limits.position_max = 0.3;
    narrow.joints[0].limits.velocity_max = 0.5;
    let narrowed = run(&mut r, Some(narrow.clone()), 1_000);
    assert_eq!(r.shared.adopted_limits(0), Some(narrow.joints[0].limits), "reported as adopted");
    assert!(narrowed.iter().all(|rec| rec.omega <= 0.5 + 1e-12), "speed above the narrowed velocity_max");
    assert!(narrowed.iter().all(|rec| rec.goal_tick <= tick(0.3) && rec.theta <= 0.3 + 1e-12));
    assert_eq!(narrowed.last().unwrap().goal_tick, tick(0.3), "the hand pushes the joint to the narrowed limit");

    let mut wide = narrow.clone();
    wide.joints[0].limits.position_max = 0.6;
    wide.joints[0].limits.velocity_max = 1e3;
    let widened = run(&mut r, Some(wide.clone()), 1_000);
    assert_eq!(r.shared.adopted_limits(0), Some(wide.joints[0].limits));
    assert!(widened.iter().any(|rec| rec.omega > 0.5), "the widened velocity_max is used");
    assert!(widened.iter().all(|rec| rec.goal_tick <= tick(0.6)));
    assert_eq!(widened.last().unwrap().goal_tick, tick(0.6), "and the widened position_max");

    // Narrowed below where the joint is: it stays where it is (no jump), never moves further out,
    // and once pushed back inside it stays inside.
    let mut below = wide.clone();
    below.joints[0].limits.position_max = 0.4;
    r.params.write(below.clone());
    let held = (0..200).map(|_| r.cycle_with(Some(push))).collect::<Vec<Record>>();
    assert!(held.iter().all(|rec| rec.goal_tick <= tick(0.6)), "never further out");
    assert_eq!(r.shared.adopted_limits(0), Some(below.joints[0].limits));
    let back = (0..1_000).map(|_| r.cycle_with(Some(-push))).collect::<Vec<Record>>();
    let inside = back.iter().position(|rec| rec.theta <= 0.4).expect("pushed back inside");
    let again = (0..1_000).map(|_| r.cycle_with(Some(push))).collect::<Vec<Record>>();
    assert!(back[inside..].iter().chain(&again).all(|rec| rec.goal_tick <= tick(0.4)));
}

#[test]
fn a_tare_removes_the_bias_it_measured() {
    let mut r = rig(free_joint(), &[(1, 2048)]);
    r.ctl.begin(r.clock.now_ns());
    r.shared.tare_request.store(10, Ordering::Relaxed);
    for _ in 0..10 {
        r.cycle_with(Some(4.0));
    }
    assert_eq!(r.shared.bias()[0], 4.0);
    let rec = r.cycle_with(Some(4.0));
    assert_eq!(rec.force, 0.0);
}

#[test]
fn bus_errors_are_counted_and_the_loop_goes_on() {
    let mut r = rig(free_joint(), &[(1, 2048)]);
    r.ctl.begin(r.clock.now_ns());
    r.bus.0.lock().unwrap().fail_writes = true;
    for _ in 0..5 {
        let rec = r.cycle_with(Some(1.0));
        assert_eq!(rec.latency_ns, -1, "no write, no latency");
    }
    r.bus.0.lock().unwrap().fail_writes = false;
    let rec = r.cycle_with(Some(1.0));
    assert!(rec.latency_ns >= 0);
    assert_eq!(r.shared.stats.bus_errors.load(Ordering::Relaxed), 5);
    let kinds = r.shared.stats.snapshot(RATE).bus_error_kinds;
    assert_eq!(kinds[0], ("write", 5), "{kinds:?}");
    assert_eq!(kinds.iter().map(|k| k.1).sum::<u64>(), 5, "every error has one kind: {kinds:?}");
    assert_eq!(r.shared.stats.cycles.load(Ordering::Relaxed), 6);
}

#[test]
fn present_positions_are_read_every_divisor_cycles() {
    let mut r = rig(free_joint(), &[(1, 2100)]);
    r.ctl.sync_read_divisor = 4;
    r.ctl.begin(r.clock.now_ns());
    let present: Vec<i64> = (0..8).map(|_| r.cycle_with(Some(0.0)).present_tick).collect();
    assert_eq!(present, vec![2100, -1, -1, -1, 2100, -1, -1, -1]);
    // A due read that fails is tried once more on the next cycle (and no more after that).
    let servos = r.bus.0.lock().unwrap().present.clone();
    let run = |r: &mut Rig, answering: bool| {
        r.bus.0.lock().unwrap().present = if answering { servos.clone() } else { Vec::new() };
        r.cycle_with(Some(0.0)).present_tick
    };
    let silent_twice: Vec<i64> = [false, false, true, true, true].iter().map(|&a| run(&mut r, a)).collect();
    assert_eq!(silent_twice, vec![-1, -1, -1, -1, 2100], "cycles 8 (due), 9 (retry), 10, 11, 12 (due)");
    let _ = [true, true, true].map(|a| run(&mut r, a)); // cycles 13..15
    let retried: Vec<i64> = [false, true, true].iter().map(|&a| run(&mut r, a)).collect();
    assert_eq!(retried, vec![-1, 2100, -1], "cycle 16 fails, 17 retries, 18 is not due");
}

/// A bus whose writes take `cost_ns` of fake time: a slow cycle.
struct SlowBus {
    inner: MemoryTransport,
    clock: FakeClock,
    cost_ns: std::rc::Rc<std::cell::Cell<u64>>,
}

// SAFETY-free: the test runs on one thread; Send is only required by the trait's bound.
unsafe impl Send for SlowBus {}

impl Transport for SlowBus {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.clock.advance(self.cost_ns.get());
        self.inner.write_all(bytes)
    }
    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> std::io::Result<usize> {
        self.inner.read_until(buf, deadline_ns)
    }
}

/// Ten cycles through the runner in `mode`, a fresh sample pushed into the ring before each
/// (bypassing the doorbell, so sample-mode cycles start at their windows' ends); the 5th
/// cycle's write takes 2.5 periods. Returns the rig, its start time and the records.
fn run_with_an_overrun(mode: crate::trigger::TriggerMode) -> (Rig, u64, Vec<Record>) {
    let mut r = rig(free_joint(), &[(1, 2048)]);
    let cost = std::rc::Rc::new(std::cell::Cell::new(100_000));
    let mut bus = SlowBus { inner: r.bus.clone(), clock: r.clock.clone(), cost_ns: cost.clone() };
    let start = r.clock.now_ns();
    let mut clock = r.clock.clone();
    let mut n = 0;
    let now = r.clock.clone();
    let bell = crate::doorbell::Doorbell::default();
    let (shared, force) = (r.shared.clone(), &mut r.force);
    crate::runner::run(&mut r.ctl, &mut bus, &mut clock, &shared, &bell, mode, || {
        n += 1;
        cost.set(if n == 5 { 2_500_000 } else { 100_000 }); // this cycle's write takes 2.5 periods
        force.push(ForceSample { t_ns: now.now_ns(), forces: [2.0, 0.0, 0.0, 0.0, 0.0, 0.0] }).unwrap();
        n <= 10
    });
    let records = std::iter::from_fn(|| r.telemetry.pop().ok()).collect();
    (r, start, records)
}

#[test]
fn overruns_are_counted_and_skipped_on_the_grid() {
    let (r, start, records) = run_with_an_overrun(crate::trigger::TriggerMode::Schedule);
    let stats = &r.shared.stats;
    assert_eq!(stats.cycles.load(Ordering::Relaxed), 10);
    assert_eq!(stats.overruns.load(Ordering::Relaxed), 2, "deadlines 6 and 7 were lost");
    let wakes: Vec<u64> = records.iter().map(|rec| rec.t_ns - start).collect();
    let expected: Vec<u64> = [1, 2, 3, 4, 5, 8, 9, 10, 11, 12].iter().map(|k| k * PERIOD).collect();
    assert_eq!(wakes, expected, "every wake is on the grid, none is doubled up");
}

#[test]
fn an_overrun_is_integrated_so_the_model_keeps_the_deadlines_time() {
    // On the schedule, and with the sample trigger (cycles at their windows' ends here): either
    // way the steps follow the grid, not the starts.
    for mode in [crate::trigger::TriggerMode::Schedule, crate::trigger::TriggerMode::default()] {
        let (_, start, records) = run_with_an_overrun(mode);
        // 10 cycles on 12 deadlines (6 and 7 lost): the model took 12 steps of h, θ_n = a·h²·n(n+1)/2.
        let a = 2.0 * 0.1 / 0.02;
        let steps = 12.0;
        let expected = a * 1e-6 * steps * (steps + 1.0) / 2.0;
        let last = records.last().unwrap();
        assert!((last.theta - expected).abs() < 1e-12, "{mode:?}: {} vs {expected}", last.theta);
        // Each record's deadline is the model's time: the lost ones caught up two steps a cycle.
        let deadlines: Vec<u64> = records.iter().map(|rec| (rec.deadline_ns - start) / PERIOD).collect();
        assert_eq!(deadlines, [1, 2, 3, 4, 5, 7, 9, 10, 11, 12], "{mode:?}");
    }
}

/// A damped joint pushed to a steady 2 rad/s (two ticks every three cycles), then cycles on the
/// deadlines `stall_at + 1 + lost`.. after `lost` deadlines were skipped: (the records after
/// the stall, the last before it, the record of an unstalled twin at the last deadline).
fn stalled(lost: u64, after: u64) -> (Vec<Record>, Record, Record) {
    let mut p = free_joint();
    p.joints[0].gains.damping = 0.1;
    let mut r = started(p.clone(), &[(1, 2048)]);
    let mut twin = started(p, &[(1, 2048)]);
    let start = r.clock.now_ns();
    let settle = 3000;
    let mut before = None;
    for k in 1..=settle {
        before = Some(cycle_at(&mut r, start + k * PERIOD, 2.0));
        cycle_at(&mut twin, start + k * PERIOD, 2.0);
    }
    let records = (settle + 1 + lost..=settle + lost + after).map(|k| cycle_at(&mut r, start + k * PERIOD, 2.0)).collect();
    let mut last = None;
    for k in settle + 1..=settle + lost + after {
        last = Some(cycle_at(&mut twin, start + k * PERIOD, 2.0));
    }
    (records, before.unwrap(), last.unwrap())
}

#[test]
fn a_stall_is_caught_up_over_the_next_cycles_without_a_goal_jump() {
    // 9 deadlines lost: caught up all at once the goal would jump 10 steps' motion (20 mrad, 13
    // ticks); two steps a cycle, it moves at most 4 mrad (3 ticks) a cycle.
    let (records, before, twin) = stalled(9, 20);
    let mut goal = before.goal_tick;
    for (n, rec) in records.iter().enumerate() {
        assert!((rec.goal_tick - goal).abs() <= 3, "cycle {n} after the stall: the goal stepped {}", rec.goal_tick - goal);
        goal = rec.goal_tick;
    }
    let deadlines: Vec<u64> = std::iter::once(&before).chain(&records).map(|r| r.deadline_ns).collect();
    let steps: Vec<u64> = deadlines.windows(2).map(|w| (w[1] - w[0]) / PERIOD).collect();
    assert!(steps.iter().all(|&s| s <= CATCH_UP_STEPS_PER_CYCLE), "{steps:?}");
    // The model kept the deadlines' time: back on them, it is where the twin that never stalled is.
    let last = records.last().unwrap();
    assert_eq!(last.deadline_ns, twin.deadline_ns);
    assert_eq!(last.theta, twin.theta, "the lost steps were all integrated");
    assert_eq!(last.goal_tick, twin.goal_tick);
}

#[test]
fn a_stall_beyond_the_cap_loses_its_time_and_still_moves_the_goal_little() {
    let (records, before, _) = stalled(15, 3);
    let first = &records[0];
    assert!((before.omega - 2.0).abs() < 1e-3, "steady: {}", before.omega);
    // Two steps, not the stall's 16: 4 mrad (3 ticks), not 32 mrad.
    assert!((first.theta - before.theta - 2.0 * 2.0 * 1e-3).abs() < 1e-5, "{} → {}", before.theta, first.theta);
    assert!((first.goal_tick - before.goal_tick).abs() <= 3);
    // The model's time restarted at the late deadline: the records' gap (16 periods, more than
    // the cap) shows the lost time, as recordings read it (`model_lapses`).
    assert_eq!(first.deadline_ns - before.deadline_ns, 16 * PERIOD);
    assert!(records.windows(2).all(|w| w[1].deadline_ns - w[0].deadline_ns == PERIOD));
}

fn lagging_servo() -> plant::servo::ServoModel {
    plant::servo::ServoModel { dead_time: 0.002, compliance: 0.01, ..plant::servo::ServoModel::first_order_lag(0.025) }
}

#[test]
fn turning_the_compensation_on_and_off_never_steps_the_goal() {
    // A damped joint under a constant push moves at a constant 1 rad/s: its lead is 27 mrad, 17 ticks.
    let mut p = free_joint();
    p.joints[0].gains.damping = 0.2;
    p.joints[0].servo = Some(lagging_servo());
    p.ramp_time_s = 0.0; // the compensation still blends, over MIN_BLEND_S
    let mut r = started(p.clone(), &[(1, 2048)]);
    for _ in 0..1000 {
        r.cycle_with(Some(2.0));
    }
    let tick = 4096.0 / std::f64::consts::TAU;
    let per_cycle = |w: f64| (w * 1e-3 * tick).ceil() as i64 + 1;
    let mut goals = vec![r.cycle_with(Some(2.0)).goal_tick];
    for weight in [1.0, 0.0] {
        let mut next = p.clone();
        next.joints[0].compensation = weight;
        r.params.write(next);
        for _ in 0..400 {
            goals.push(r.cycle_with(Some(2.0)).goal_tick);
        }
        let rec = r.cycle_with(Some(2.0));
        let lead = weight * plant::servo::lead(&lagging_servo(), rec.omega, 0.0, rec.torque);
        assert_eq!(rec.goal_tick, 2048 + ((rec.theta + lead) * tick).round() as i64, "weight {weight}");
        goals.push(rec.goal_tick);
    }
    // Per cycle: the joint's own motion (1 rad/s) plus the blend's share of the 17-tick lead.
    let limit = per_cycle(1.0) + (0.027 * tick * 1e-3 / crate::compensation::MIN_BLEND_S).ceil() as i64;
    let worst = goals.windows(2).map(|w| (w[1] - w[0]).abs()).max().unwrap();
    assert!(worst <= limit, "a step of {worst} ticks (limit {limit})");
}

/// A joint moving at 0.5 rad/s (inside its range for the whole run) with compensation on, its horn read every cycle `overshoot` leads
/// past the goal (0: where the goal says); returns (fallbacks counted, the last lead in ticks,
/// the largest goal step in ticks).
fn horn_overshooting(overshoot: f64, cycles: usize) -> (u64, i64, i64) {
    let mut p = free_joint();
    p.joints[0].gains.damping = 0.2;
    p.joints[0].servo = Some(lagging_servo());
    p.joints[0].compensation = 1.0;
    let mut r = started(p, &[(1, 2048)]);
    r.ctl.sync_read_divisor = 1;
    let tick = 4096.0 / std::f64::consts::TAU;
    let (mut last, mut worst, mut lead) = (r.cycle_with(Some(1.0)), 0, 0);
    for _ in 0..cycles {
        lead = last.goal_tick - 2048 - (last.theta * tick).round() as i64;
        let horn = last.goal_tick + (overshoot * lead as f64).round() as i64;
        r.bus.0.lock().unwrap().present = vec![(1, horn)];
        let rec = r.cycle_with(Some(1.0));
        worst = worst.max((rec.goal_tick - last.goal_tick).abs());
        last = rec;
    }
    (r.shared.stats.compensation_fallbacks.load(Ordering::Relaxed), lead, worst)
}

#[test]
fn a_compensation_that_makes_the_horn_worse_is_blended_out_without_a_jump() {
    let (fallbacks, lead, _) = horn_overshooting(0.0, 3500);
    assert_eq!(fallbacks, 0, "a horn where the goal says: the compensation stays");
    assert!((8..=10).contains(&lead), "with its lead of 13.5 mrad: {lead} ticks");
    let (fallbacks, lead, worst) = horn_overshooting(2.0, 3500);
    assert_eq!(fallbacks, 1, "a horn two leads past the goal: counted once");
    assert!(lead.abs() <= 1, "and blended out: a lead of {lead} ticks left");
    // The joint's own motion (0.5 rad/s: 0.33 tick a cycle) plus the blend's share of 9 ticks.
    assert!(worst <= 2, "no jump: a step of {worst} ticks");
}

#[test]
fn a_position_limit_stops_the_model_without_kicking_the_goal_back() {
    let mut p = free_joint();
    p.joints[0].servo = Some(plant::servo::ServoModel { inertial_time: 0.02, ..lagging_servo() });
    p.joints[0].compensation = 1.0;
    p.joints[0].limits.position_max = 0.05;
    let mut r = started(p, &[(1, 2048)]);
    let goals: Vec<i64> = (0..400).map(|_| r.cycle_with(Some(2.0)).goal_tick).collect();
    let limit_tick = 2048 + (0.05 * 4096.0 / std::f64::consts::TAU).round() as i64;
    assert!(goals.iter().all(|&g| g <= limit_tick), "never past the limit");
    // At rest against the limit the lead is only the hand's deflection (s·τ = 2 mrad, 1.3 ticks).
    assert!(goals.windows(2).all(|w| w[1] >= w[0] - 2), "no kick back from it: {goals:?}");
}

/// Runs one cycle whose deadline is `deadline` (the clock wakes on it), with a fresh sample of `fx`.
fn cycle_at(r: &mut Rig, deadline: u64, fx: f64) -> Record {
    let mut clock = r.clock.clone();
    clock.sleep_until(deadline);
    r.force.push(ForceSample { t_ns: r.clock.now_ns(), forces: [fx, 0.0, 0.0, 0.0, 0.0, 0.0] }).unwrap();
    let mut bus = r.bus.clone();
    r.ctl.run_cycle(&mut bus, &r.clock, deadline, deadline);
    r.telemetry.pop().unwrap()
}

#[test]
fn a_grid_that_shifts_or_stretches_keeps_the_model_within_half_a_period_of_it() {
    // Deadlines from a phase-locked grid: 0.1 % longer than the nominal period, with a bounded
    // jitter of ±0.3 periods and one phase step of +0.4 periods. The model's time (whole steps)
    // may lag or lead a deadline by at most half a period, and never drifts away from it.
    let mut r = started(free_joint(), &[(1, 2048)]);
    let start = r.clock.now_ns();
    let mut steps = 0u64;
    let a = 0.2 * 0.1 / 0.02;
    for k in 1..=3000u64 {
        let jitter = ((k * 7919 % 13) as f64 / 12.0 - 0.5) * 0.6;
        let phase = if k > 1500 { 0.4 } else { 0.0 };
        let deadline = start + ((k as f64 * 1.001 + jitter + phase) * PERIOD as f64) as u64;
        let rec = cycle_at(&mut r, deadline, 0.2);
        steps = ((2.0 * rec.theta / (a * 1e-6) + 0.25).sqrt() - 0.5).round() as u64; // θ_n = a·h²·n(n+1)/2
        let model_ns = r.ctl.model_ns.unwrap();
        assert!(model_ns.abs_diff(deadline) <= PERIOD / 2, "cycle {k}: model {model_ns}, deadline {deadline}");
    }
    let elapsed = (r.ctl.model_ns.unwrap() - start) as f64 / PERIOD as f64;
    assert!((steps as f64 - elapsed).abs() <= 1.0, "{steps} steps over {elapsed} periods");
    assert!(steps > 3000, "the stretched grid's extra time was integrated: {steps}");
}

/// A damped joint with the lagging servo compensated, pushed to a steady 1 rad/s (its lead is
/// 17 ticks): the set, the rig and the last (good) record.
fn pushed_with_compensation() -> (LoopParams, Rig, Record) {
    let mut p = free_joint();
    p.joints[0].gains.damping = 0.2;
    p.joints[0].servo = Some(lagging_servo());
    p.joints[0].compensation = 1.0;
    let mut r = started(p.clone(), &[(1, 2048)]);
    for _ in 0..300 {
        r.cycle_with(Some(2.0));
    }
    let good = r.cycle_with(Some(2.0));
    assert!(good.goal_tick > 2048 + 10 && good.fault == 0);
    (p, r, good)
}

#[test]
fn a_non_finite_compensated_goal_is_a_fault_and_the_goal_stays() {
    let (p, mut r, good) = pushed_with_compensation();
    let mut bad = p.clone();
    bad.joints[0].compensation = f64::NAN; // the gate refuses this; written straight to the buffer here
    r.params.write(bad);
    for _ in 0..20 {
        let rec = r.cycle_with(Some(2.0));
        assert_eq!((rec.goal_tick, rec.fault), (good.goal_tick, FaultKind::ModelStateInvalid.bit()));
        assert_eq!((rec.theta, rec.omega, rec.mode), (good.theta, 0.0, LoopMode::Faulted as i64));
    }
    assert_eq!(model_faults(&r), 1);
    r.params.write(p);
    let recovered = r.cycle_with(Some(2.0));
    assert_eq!((recovered.fault, recovered.mode), (0, LoopMode::Running as i64));
    assert!((recovered.goal_tick - good.goal_tick).abs() <= 20, "within the lead it held with");
}

#[test]
fn a_fault_with_compensation_on_keeps_the_led_goal() {
    let (_, mut r, good) = pushed_with_compensation();
    r.ctl.joints[0].state.theta = f64::NAN;
    let held = r.cycle_with(Some(2.0));
    assert_eq!((held.goal_tick, held.fault), (good.goal_tick, FaultKind::ModelStateInvalid.bit()));
    let after = r.cycle_with(Some(2.0));
    assert_eq!(after.fault, 0);
    assert!((after.goal_tick - good.goal_tick).abs() <= 2, "no jump when it runs again");
}

/// Counts the allocations made by the current thread (const thread-locals never allocate).
pub(crate) mod counting {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    thread_local! {
        pub static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    }

    pub struct Counting;

    // SAFETY: forwards to the system allocator unchanged; only counts.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            ALLOCATIONS.with(|c| c.set(c.get() + 1));
            System.alloc(layout)
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            System.dealloc(ptr, layout)
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            ALLOCATIONS.with(|c| c.set(c.get() + 1));
            System.realloc(ptr, layout, new_size)
        }
    }

    #[global_allocator]
    static GLOBAL: Counting = Counting;

    pub fn count() -> u64 {
        ALLOCATIONS.with(|c| c.get())
    }
}

/// A bus that accepts every write and never answers: nothing of its own allocates.
struct NullBus;

impl Transport for NullBus {
    fn write_all(&mut self, _bytes: &[u8]) -> std::io::Result<()> {
        Ok(())
    }
    fn read_until(&mut self, _buf: &mut [u8], _deadline_ns: u64) -> std::io::Result<usize> {
        Ok(0)
    }
}

#[test]
fn a_cycle_allocates_nothing() {
    let mut p = params(3);
    p.ramp_time_s = 0.05;
    p.sensor.lowpass_hz = 20.0;
    p.sensor.deadband = 0.1;
    let mut r = rig(p.clone(), &[(1, 2048), (2, 2048), (3, 2048)]);
    r.ctl.sync_read_divisor = 7; // reads time out on this bus: the error path runs too
    r.ctl.begin(r.clock.now_ns());
    let mut next = p.clone();
    next.joints[1].gains.damping = 0.2;
    next.joints[2].servo = Some(lagging_servo());
    next.joints[2].compensation = 1.0;
    next.bias = [0.5; 6];
    next.bias_generation = 1;
    r.params.write(next);
    r.shared.tare_request.store(5, Ordering::Relaxed);
    let probe = counting::count();
    std::hint::black_box(Box::new(1u8));
    assert_eq!(counting::count(), probe + 1, "the counter sees this thread's allocations");
    let mut allocations = 0;
    for k in 0..400u64 {
        let deadline = r.clock.now_ns() + PERIOD;
        r.clock.clone().sleep_until(deadline);
        if k < 200 {
            r.force.push(ForceSample { t_ns: r.clock.now_ns(), forces: [1.0, 2.0, 0.0, 0.0, 0.0, 0.0] }).unwrap();
        }
        let before = counting::count();
        r.ctl.run_cycle(&mut NullBus, &r.clock, deadline, deadline);
        allocations += counting::count() - before;
        while r.telemetry.pop().is_ok() {}
    }
    let stats = &r.shared.stats;
    assert_eq!(stats.sensor_stale_events.load(Ordering::Relaxed), 1, "the stale path ran");
    assert!(stats.bus_errors.load(Ordering::Relaxed) > 0, "the bus-error path ran");
    assert_eq!(allocations, 0, "a cycle allocated");
}

fn mode_now(r: &Rig) -> crate::fault::LoopMode {
    r.shared.stats.faults.mode()
}

fn model_faults(r: &Rig) -> u64 {
    r.shared.stats.faults.events(FaultKind::ModelStateInvalid)
}

/// A free joint pushed for `cycles` cycles; the rig and the last (good) record.
fn pushed(cycles: usize) -> (Rig, Record) {
    let mut r = started(free_joint(), &[(1, 2048)]);
    for _ in 0..cycles {
        r.cycle_with(Some(3.0));
    }
    let good = r.cycle_with(Some(3.0));
    (r, good)
}

#[test]
fn an_injected_nan_state_holds_the_last_good_goal_and_raises_a_fault() {
    let (mut r, good) = pushed(100);
    assert!(good.goal_tick > 2048 && good.mode == LoopMode::Running as i64 && good.fault == 0);
    r.ctl.joints[0].state.theta = f64::NAN;
    let held = r.cycle_with(Some(3.0));
    assert_eq!(held.goal_tick, good.goal_tick, "the goal stays where it was (NaN as i64 is zero_tick: a jump)");
    assert_eq!((held.theta, held.omega), (good.theta, 0.0), "the last good state, at rest");
    assert_eq!(held.fault, FaultKind::ModelStateInvalid.bit());
    assert_eq!(held.mode, LoopMode::Faulted as i64);
    assert_eq!((model_faults(&r), mode_now(&r)), (1, LoopMode::Faulted));
    // The cause is gone (the state was restored): the next cycle runs again, from rest.
    let after = r.cycle_with(Some(3.0));
    assert_eq!((after.fault, after.mode), (0, LoopMode::Running as i64));
    assert!(after.theta > good.theta && (after.goal_tick - good.goal_tick).abs() <= 1);
    assert_eq!(model_faults(&r), 1);
}

#[test]
fn a_state_out_of_the_envelope_is_a_fault_too() {
    let mut r = started(free_joint(), &[(1, 2048)]);
    let good = r.cycle_with(Some(0.0));
    r.ctl.joints[0].state.omega = 1e300;
    let held = r.cycle_with(Some(0.0));
    assert_eq!((held.goal_tick, held.omega, held.fault), (good.goal_tick, 0.0, FaultKind::ModelStateInvalid.bit()));
}

#[test]
fn gains_that_bypassed_the_gate_hold_the_joint_until_a_good_set_arrives() {
    let (mut r, good) = pushed(50);
    let mut bad = free_joint();
    bad.joints[0].gains.inertia = 0.0; // the gate refuses this; written straight to the buffer here
    r.params.write(bad);
    for _ in 0..20 {
        let rec = r.cycle_with(Some(3.0));
        assert_eq!((rec.goal_tick, rec.omega, rec.mode), (good.goal_tick, 0.0, LoopMode::Faulted as i64));
        assert!(rec.theta.is_finite());
    }
    assert_eq!(model_faults(&r), 1, "one event for the whole episode");
    r.params.write(free_joint());
    let recovered = r.cycle_with(Some(3.0));
    assert_eq!(recovered.mode, LoopMode::Running as i64);
    assert!((recovered.goal_tick - good.goal_tick).abs() <= 1, "it starts again from where it held");
}

#[test]
fn a_stale_hold_is_the_holding_mode_not_a_fault() {
    let mut r = started(free_joint(), &[(1, 2048)]);
    r.cycle_with(Some(1.0));
    let held = (0..60).map(|_| r.cycle_with(None)).last().unwrap();
    assert_eq!((held.mode, held.fault), (LoopMode::Holding as i64, 0));
    assert_eq!(model_faults(&r), 0);
}

/// A set the gate accepts, drawn across the envelope (gains log-uniform, limits anywhere valid).
fn accepted_set() -> impl proptest::strategy::Strategy<Value = LoopParams> {
    use crate::params::envelope;
    use crate::params::tests::{accepted_gains, reach};
    use proptest::prelude::*;
    let limits = (-3.1f64..3.1, 0.01f64..3.0, 0.01f64..envelope::VELOCITY_MAX, 1.0f64..envelope::ACCELERATION_MAX);
    (accepted_gains(), limits, 0.0f64..0.05, proptest::collection::vec(-100.0f64..100.0, 6)).prop_filter_map(
        "the set must pass the gate",
        |(gains, (lo, width, v, a), ramp, bias)| {
            let mut p = params(1);
            p.joints[0].gains = gains;
            p.joints[0].limits = Limits { position_min: lo, position_max: (lo + width).min(std::f64::consts::PI), velocity_max: v, acceleration_max: a };
            p.ramp_time_s = ramp;
            p.bias.copy_from_slice(&bias);
            p.bias_generation = 1;
            p.validate(&reach(1), RATE).ok().map(|_| p)
        },
    )
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]

    /// Any sequence of accepted sets, each adopted (and ramped into) while a random force
    /// pushes: every goal stays in the goal range, every state finite, no fault is raised, and
    /// no cycle moves the goal by more than the fastest accepted speed allows.
    #[test]
    fn accepted_sets_keep_the_goals_finite_and_jump_free(
        sets in proptest::collection::vec((accepted_set(), 1usize..60), 1..6),
        forces in proptest::collection::vec(-500.0f64..500.0, 8),
    ) {
        let mut r = started(params(1), &[(1, 2048)]);
        let mut previous = r.cycle_with(Some(0.0)).goal_tick;
        let mut k = 0;
        for (set, cycles) in sets {
            // Limits apply at once: |Δθ| ≤ h·velocity_max of this set, plus a tick of rounding.
            let max_step = set.joints[0].limits.velocity_max / RATE * 4096.0 / std::f64::consts::TAU + 1.0;
            r.params.write(set);
            for _ in 0..cycles {
                let rec = r.cycle_with(Some(forces[k % forces.len()]));
                k += 1;
                proptest::prop_assert!(rec.theta.is_finite() && rec.omega.is_finite());
                proptest::prop_assert!((0..=4095).contains(&rec.goal_tick));
                proptest::prop_assert!(((rec.goal_tick - previous).abs() as f64) <= max_step,
                    "goal {} → {}", previous, rec.goal_tick);
                proptest::prop_assert_eq!(rec.fault, 0);
                previous = rec.goal_tick;
            }
        }
    }
}

#[test]
fn a_joint_lighter_than_the_servo_leads_with_its_share_of_the_acceleration() {
    // The MX-64 bench's servo model (J = T·m/s = 0.0146 kg·m²) on a joint at the daemon's floor
    // of 1e-4 kg·m², pushed from rest: α = τ/I reaches 10³ rad/s², whose whole inertial lead
    // (T·m·α) would be clipped at MAX_LEAD; the loop hands the compensation the joint's inertia, so
    // it leads with the share 2·I/J of it, 2·T·m·τ/J at most (docs/fidelity.md, "The compensation's
    // lead at light inertias").
    let model = plant::servo::ServoModel {
        inertial_time: 0.0213,
        compliance: 0.0248,
        deadband: 0.00206,
        ..plant::servo::ServoModel::first_order_lag(0.017)
    };
    let mut p = free_joint();
    p.joints[0].gains.inertia = 1e-4;
    p.joints[0].gains.damping = 0.0347;
    p.joints[0].servo = Some(model);
    p.joints[0].compensation = 1.0;
    let mut r = started(p, &[(1, 2048)]);
    let tick = 4096.0 / std::f64::consts::TAU;
    let own = model.time_constant * model.inertial_time / model.compliance;
    let mut fastest: f64 = 0.0;
    for _ in 0..40 {
        let rec = r.cycle_with(Some(4.0));
        // The goal less the model's angle and the lead's terms without the acceleration.
        let fade = plant::servo::FRICTION_FADE_VELOCITY.max(model.deadband / model.time_constant);
        let rest = plant::servo::lead_fading(&model, rec.omega, 0.0, rec.torque, fade);
        let inertial = (rec.goal_tick - 2048) as f64 / tick - rec.theta - rest;
        let bound = model.time_constant * model.inertial_time * rec.torque.abs() / (crate::compensation::LIGHT_BELOW * own) + 0.5 / tick;
        assert!(inertial.abs() <= bound + 1e-12, "an inertial lead of {inertial} rad (at most {bound})");
        fastest = fastest.max(rec.omega);
    }
    // 0.4 N·m over 0.0347 N·m·s/rad: 11.5 rad/s within 40 ms, an acceleration of 10³ rad/s².
    assert!(fastest > 5.0, "the push accelerated the joint: {fastest} rad/s");
}
