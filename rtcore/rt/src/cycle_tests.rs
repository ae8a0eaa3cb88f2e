//! The tick logic against the in-memory bus and the fake clock: what a cycle writes, when it
//! holds, how parameter sets arrive, and how the pacing counts overruns.
use super::*;
use crate::bus::memory::MemoryTransport;
use crate::bus::Registers;
use crate::clock::fake::FakeClock;
use crate::params::tests::params;
use crate::sensor::ForceSample;
use dxl::Protocol;

const RATE: f64 = 1000.0;
const PERIOD: u64 = 1_000_000;

struct Rig {
    ctl: Controller,
    bus: MemoryTransport,
    clock: FakeClock,
    force: rtrb::Producer<ForceSample>,
    params: triple_buffer::Input<LoopParams>,
    telemetry: rtrb::Consumer<Record>,
    shared: Arc<Shared>,
}

fn rig(initial: LoopParams, present: &[(u8, i64)]) -> Rig {
    let ids: Vec<u8> = present.iter().map(|p| p.0).collect();
    let regs = Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 };
    let (force, force_ring) = rtrb::RingBuffer::new(64);
    let (telemetry_tx, telemetry) = rtrb::RingBuffer::new(1 << 16);
    let (params_in, params_out) = triple_buffer::triple_buffer(&initial);
    let shared = Arc::new(Shared::default());
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
    let bus = MemoryTransport::new(true, present);
    Rig { ctl, bus, clock: FakeClock::new(1_000_000_000, 0), force, params: params_in, telemetry, shared }
}

/// A rig whose controller already read the present positions and started its stale clock.
fn started(initial: LoopParams, present: &[(u8, i64)]) -> Rig {
    let mut r = rig(initial, present);
    let mut bus = r.bus.clone();
    r.ctl.start_at_present(&mut bus, 0, false).unwrap();
    r.ctl.begin(r.clock.now_ns());
    r
}

impl Rig {
    /// Pushes a fresh sample with `fx` and runs one cycle on the grid.
    fn cycle_with(&mut self, fx: Option<f64>) -> Record {
        let deadline = self.clock.now_ns() + PERIOD;
        let mut clock = self.clock.clone();
        clock.sleep_until(deadline);
        if let Some(fx) = fx {
            self.force.push(ForceSample { t_ns: self.clock.now_ns(), forces: [fx, 0.0, 0.0, 0.0, 0.0, 0.0] }).unwrap();
        }
        let mut bus = self.bus.clone();
        self.ctl.run_cycle(&mut bus, &self.clock, deadline);
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

fn free_joint() -> LoopParams {
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
    assert_eq!(r.bus.written().len(), 301, "one SyncRead at start, then one SyncWrite per cycle");
}

#[test]
fn the_loop_starts_where_the_servo_is() {
    let mut r = started(free_joint(), &[(1, 3000)]);
    let rec = r.cycle_with(Some(0.0));
    assert_eq!(rec.goal_tick, 3000);
    let mut enabling = rig(free_joint(), &[(1, 1234)]);
    let mut bus = enabling.bus.clone();
    enabling.ctl.start_at_present(&mut bus, 0, true).unwrap();
    let written = enabling.bus.written();
    assert_eq!(written.len(), 3, "read, goal = present, then torque on");
    assert_eq!(enabling.last_goal_written_in(&written[1]), 1234);
    assert_eq!(&written[2][8..13], &[64, 0, 1, 0, 1], "Torque Enable = 1 for id 1");
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
    assert_eq!(r.shared.stats.cycles.load(Ordering::Relaxed), 6);
}

#[test]
fn present_positions_are_read_every_divisor_cycles() {
    let mut r = rig(free_joint(), &[(1, 2100)]);
    r.ctl.sync_read_divisor = 4;
    r.ctl.begin(r.clock.now_ns());
    let present: Vec<i64> = (0..8).map(|_| r.cycle_with(Some(0.0)).present_tick).collect();
    assert_eq!(present, vec![2100, -1, -1, -1, 2100, -1, -1, -1]);
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

#[test]
fn overruns_are_counted_and_skipped_on_the_grid() {
    let mut r = rig(free_joint(), &[(1, 2048)]);
    let cost = std::rc::Rc::new(std::cell::Cell::new(100_000));
    let mut bus = SlowBus { inner: r.bus.clone(), clock: r.clock.clone(), cost_ns: cost.clone() };
    let start = r.clock.now_ns();
    let mut clock = r.clock.clone();
    let mut n = 0;
    let bell = crate::doorbell::Doorbell::default();
    crate::runner::run(&mut r.ctl, &mut bus, &mut clock, &r.shared.clone(), &bell, crate::trigger::TriggerMode::Schedule, || {
        n += 1;
        if n == 5 {
            cost.set(2_500_000); // this cycle's write takes 2.5 periods
        } else {
            cost.set(100_000);
        }
        n <= 10
    });
    let stats = &r.shared.stats;
    assert_eq!(stats.cycles.load(Ordering::Relaxed), 10);
    assert_eq!(stats.overruns.load(Ordering::Relaxed), 2, "deadlines 6 and 7 were lost");
    let wakes: Vec<u64> = std::iter::from_fn(|| r.telemetry.pop().ok()).map(|rec| rec.t_ns - start).collect();
    let expected: Vec<u64> = [1, 2, 3, 4, 5, 8, 9, 10, 11, 12].iter().map(|k| k * PERIOD).collect();
    assert_eq!(wakes, expected, "every wake is on the grid, none is doubled up");
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
        r.ctl.run_cycle(&mut NullBus, &r.clock, deadline);
        allocations += counting::count() - before;
        while r.telemetry.pop().is_ok() {}
    }
    let stats = &r.shared.stats;
    assert_eq!(stats.sensor_stale_events.load(Ordering::Relaxed), 1, "the stale path ran");
    assert!(stats.bus_errors.load(Ordering::Relaxed) > 0, "the bus-error path ran");
    assert_eq!(allocations, 0, "a cycle allocated");
}
