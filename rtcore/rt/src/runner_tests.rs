//! What starts each cycle, for every way a sensor can behave: on time at the loop's rate, late,
//! stopped, jittering, faster or slower than the loop. A scripted sensor pushes samples through
//! the real `ForceSink` at fake-clock times, and the real runner and controller run against a
//! bus whose writes take a fixed fake time; every figure below is exact, none is timed.
use super::*;
use crate::bus::{JointBus, Registers};
use crate::clock::fake::FakeClock;
use crate::cycle::{ControllerParts, JointWiring};
use crate::handle::ForceSink;
use crate::joint::TickMap;
use crate::params::tests::params;
use crate::params::{JointGains, Limits};
use crate::sensor::ForceSample;
use crate::telemetry::Record;
use crate::trigger::TriggerSnapshot;
use dxl::Protocol;
use std::cell::Cell;
use std::collections::VecDeque;
use std::rc::Rc;
use std::sync::Arc;

const P: u64 = 1_000_000; // 1 kHz
const T0: u64 = 1_000_000_000;
/// What one SyncWrite costs in fake time: the latency of a sample caught on arrival.
const WRITE_NS: u64 = 20_000;
const FX: f64 = 2.0;

/// A bus whose writes take `cost_ns` of fake time and that never answers; it keeps nothing, so
/// it allocates nothing.
struct TimedBus {
    clock: FakeClock,
    cost_ns: Rc<Cell<u64>>,
}

// SAFETY-free: the test runs on one thread; Send is only required by the trait's bound.
unsafe impl Send for TimedBus {}

impl Transport for TimedBus {
    fn write_all(&mut self, _bytes: &[u8]) -> std::io::Result<()> {
        self.clock.advance(self.cost_ns.get());
        Ok(())
    }
    fn read_until(&mut self, _buf: &mut [u8], _deadline_ns: u64) -> std::io::Result<usize> {
        Ok(0)
    }
}

/// The fake clock with a sensor behind it: each scripted sample is pushed through the real sink
/// (ring + doorbell + arrival estimate) at its own time, as time passes.
struct ScriptedSensor {
    clock: FakeClock,
    arrivals: VecDeque<u64>,
    sink: ForceSink,
}

impl ScriptedSensor {
    fn deliver_due(&mut self) {
        while let Some(&t) = self.arrivals.front() {
            if t > self.clock.now.get() {
                break;
            }
            self.arrivals.pop_front();
            assert!(self.sink.push_at(ForceSample { t_ns: t, forces: [FX, 0.0, 0.0, 0.0, 0.0, 0.0] }, t));
        }
    }
}

impl Clock for ScriptedSensor {
    fn now_ns(&self) -> u64 {
        self.clock.now.get()
    }
    fn sleep_until(&mut self, deadline_ns: u64) {
        self.clock.sleep_until(deadline_ns);
        self.deliver_due();
    }
    fn wait_for_ring(&mut self, bell: &Doorbell, seq: u32, deadline_ns: u64) {
        self.deliver_due();
        if bell.seq() != seq {
            return;
        }
        match self.arrivals.front() {
            Some(&t) if t < deadline_ns => {
                self.clock.now.set(t.max(self.clock.now.get()) + self.clock.wake_latency_ns);
                self.deliver_due();
            }
            _ => self.sleep_until(deadline_ns),
        }
    }
}

struct Rig {
    ctl: Controller,
    shared: Arc<Shared>,
    bell: Arc<Doorbell>,
    telemetry: rtrb::Consumer<Record>,
    sensor: ScriptedSensor,
    bus: TimedBus,
}

/// One free joint (I = 0.02, no damping or friction) and a sensor that pushes at `arrivals`.
fn rig(arrivals: impl IntoIterator<Item = u64>) -> Rig {
    let mut p = params(1);
    p.joints[0].gains = JointGains { inertia: 0.02, damping: 0.0, coulomb: 0.0, lever_arm: 0.1 };
    p.joints[0].limits = Limits { position_min: -1e3, position_max: 1e3, velocity_max: 1e3, acceleration_max: 1e6 };
    let regs = Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 };
    let (force_tx, force_rx) = rtrb::RingBuffer::new(1 << 12);
    let (telemetry_tx, telemetry) = rtrb::RingBuffer::new(1 << 16);
    let (_params_in, params_out) = triple_buffer::triple_buffer(&p);
    let shared = Arc::new(Shared::default());
    let bell = Arc::new(Doorbell::default());
    let ticks = TickMap { zero_tick: 2048, direction: 1, ticks_per_rev: 4096.0, tick_min: 0, tick_max: 4095 };
    let ctl = Controller::new(ControllerParts {
        rate_hz: 1e9 / P as f64,
        joints: vec![JointWiring { id: 1, axis: 0, ticks }],
        initial: p,
        bus: JointBus::new(Protocol::V2, regs, &[1]),
        sync_read_divisor: 0,
        force_ring: force_rx,
        params: params_out,
        telemetry: telemetry_tx,
        shared: shared.clone(),
    });
    let clock = FakeClock::new(T0, 0);
    let bus = TimedBus { clock: clock.clone(), cost_ns: Rc::new(Cell::new(WRITE_NS)) };
    let sink = ForceSink::new(force_tx, bell.clone());
    Rig { ctl, shared, bell, telemetry, sensor: ScriptedSensor { clock, arrivals: arrivals.into_iter().collect(), sink }, bus }
}

/// Arrivals every `interval` from `first`, `n` of them.
fn every(first: u64, interval: u64, n: u64) -> impl Iterator<Item = u64> {
    (0..n).map(move |k| first + k * interval)
}

impl Rig {
    /// Runs `cycles` cycles; returns their telemetry records.
    fn run(&mut self, mode: TriggerMode, cycles: u64) -> Vec<Record> {
        let mut n = 0;
        run(&mut self.ctl, &mut self.bus, &mut self.sensor, &self.shared, &self.bell, mode, || {
            n += 1;
            n <= cycles
        });
        std::iter::from_fn(|| self.telemetry.pop().ok()).collect()
    }

    fn starts(&self) -> TriggerSnapshot {
        self.shared.trigger.snapshot()
    }

    fn counter(&self, c: &std::sync::atomic::AtomicU64) -> u64 {
        c.load(Ordering::Relaxed)
    }
}

fn latencies(records: &[Record]) -> Vec<u64> {
    records.iter().filter(|r| r.latency_ns >= 0).map(|r| r.latency_ns as u64).collect()
}

/// The model integrated exactly h = 1/rate per cycle: from rest under a constant torque, the
/// semi-implicit Euler angle after n steps is a·h²·n(n+1)/2, whatever the cycles' timing.
fn assert_fixed_step(records: &[Record]) {
    let (h, a) = (P as f64 / 1e9, FX * 0.1 / 0.02);
    for (n, rec) in records.iter().enumerate().map(|(k, r)| ((k + 1) as f64, r)) {
        let theta = a * h * h * n * (n + 1.0) / 2.0;
        assert!((rec.theta - theta).abs() < 1e-9 * theta.max(1.0), "cycle {n}: θ {} vs {theta}", rec.theta);
    }
}

const LOCKED: TriggerMode = TriggerMode::Sample { phase_lock: true };
const UNLOCKED: TriggerMode = TriggerMode::Sample { phase_lock: false };

#[test]
fn on_the_schedule_a_sample_waits_for_the_next_deadline() {
    // The sensor pushes at 95 % of each period: each sample waits 5 % of a period.
    let mut r = rig(every(T0 + P - 50_000, P, 400));
    let recs = r.run(TriggerMode::Schedule, 300);
    assert!(latencies(&recs).iter().all(|&l| l == 50_000 + WRITE_NS));
    let wakes: Vec<u64> = recs.iter().map(|rec| rec.t_ns - T0).collect();
    assert_eq!(wakes, (1..=300).map(|k| k * P).collect::<Vec<_>>(), "on the grid");
    assert_eq!(r.starts().schedule, 300);
}

#[test]
fn a_sensor_at_the_loop_rate_is_caught_on_arrival_once_the_phase_lock_moved_the_grid() {
    // The same sensor, its arrivals just after each window (the worst phase).
    let mut r = rig(every(T0 + P - 50_000, P, 1_200));
    let recs = r.run(LOCKED, 1_000);
    assert_fixed_step(&recs);
    let lat = latencies(&recs);
    assert_eq!(lat.len(), 1_000, "every cycle used a new sample");
    // Until the sensor's period is known (8 intervals) and the grid has then moved 5 % of a
    // period (25 cycles at period/500), the sample waits for the opening, never longer than it
    // did on the schedule; from then on, none waits at all.
    assert!(lat.iter().all(|&l| l <= 50_000 + WRITE_NS));
    assert!(lat[35..].iter().all(|&l| l == WRITE_NS), "{:?}", &lat[..40]);
    let s = r.starts();
    assert_eq!((s.open + s.arrival, s.fallback), (1_000, 0));
    assert!(s.open <= 35);
    // Locked mid-window: the arrivals sit 45 % into the window, within a microsecond or two.
    assert!(s.phase_error_us.abs() < 2.0, "{s:?}");
    // One cycle per period throughout: 1000 cycles took 1000 periods, to 0.2 %.
    let span = recs[999].t_ns - recs[0].t_ns;
    assert!((span as f64 / (999 * P) as f64 - 1.0).abs() < 0.002, "{span}");
}

#[test]
fn without_the_phase_lock_the_same_sensor_waits_for_each_opening() {
    let mut r = rig(every(T0 + P - 50_000, P, 600));
    let lat = latencies(&r.run(UNLOCKED, 500));
    assert!(lat.iter().all(|&l| l == 50_000 + WRITE_NS), "{:?}", &lat[..10]);
    assert_eq!(r.starts().open, 500);
}

#[test]
fn a_stopped_sensor_falls_back_to_the_schedule_and_the_joint_holds() {
    // Mid-window arrivals for 100 periods, then nothing.
    let mut r = rig(every(T0 + P + 450_000, P, 100));
    let recs = r.run(LOCKED, 300);
    assert_eq!(r.starts().arrival, 100);
    assert_eq!(r.starts().fallback, 200);
    // Without samples every cycle starts at its window's end, one period apart.
    let gaps: Vec<u64> = recs[101..].windows(2).map(|w| w[1].t_ns - w[0].t_ns).collect();
    assert!(gaps.iter().all(|&g| g == P), "{:?}", &gaps[..5]);
    assert!(recs[101..].iter().all(|rec| rec.latency_ns == -1 && rec.period_error_ns == 0));
    // 50 ms after the last sample the force is stale: held, counted once.
    assert_eq!(r.counter(&r.shared.stats.sensor_stale_events), 1);
    let held = recs.iter().position(|rec| rec.omega == 0.0).unwrap();
    assert!((148..=152).contains(&held), "held at cycle {held}");
    assert!(recs[held..].iter().all(|rec| rec.omega == 0.0 && rec.theta == recs[held].theta));
}

#[test]
fn a_late_sample_is_used_at_the_next_opening_and_adds_no_cycle() {
    // Mid-window arrivals, except the 50th, which comes after its window has closed.
    let mut arrivals: Vec<u64> = every(T0 + P + 450_000, P, 200).collect();
    arrivals[49] += 500_000;
    let mut r = rig(arrivals);
    let recs = r.run(LOCKED, 150);
    assert_fixed_step(&recs);
    let causes: Vec<(i64, i64)> = recs[48..53].iter().map(|rec| (rec.latency_ns, rec.period_error_ns)).collect();
    // Cycle 50: its window ended without the sample (schedule, no new sample). Cycle 51: the
    // late sample waited 5 % of a period for the opening. Cycle 52: the sample of cycle 51's
    // window waited since then; a fresher one is due inside the window, so the cycle waits for
    // that one and uses it on arrival.
    let w = WRITE_NS as i64;
    assert_eq!(causes, vec![(w, 0), (-1, 0), (50_000 + w, 0), (w, 0), (w, 0)]);
    let s = r.starts();
    assert_eq!((s.fallback, s.open, s.arrival), (1, 1, 148));
}

/// A deterministic jitter in [−amp, amp] (an LCG, so the test is the same every run).
fn jitter(k: u64, amp: u64) -> i64 {
    let x = k.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407) >> 33;
    (x % (2 * amp + 1)) as i64 - amp as i64
}

#[test]
fn a_jittering_sensor_is_caught_on_arrival_in_every_window() {
    // ±30 % of a period around mid-window.
    let arrivals = (0..800).map(|k| (T0 + P + 450_000 + k * P).saturating_add_signed(jitter(k, 300_000)));
    let mut r = rig(arrivals);
    let recs = r.run(LOCKED, 700);
    assert_fixed_step(&recs);
    assert_eq!(r.counter(&r.shared.stats.overruns), 0);
    assert_eq!(r.starts().arrival, 700);
    assert!(latencies(&recs).iter().all(|&l| l == WRITE_NS));
    assert!(r.starts().phase_error_us.abs() < 300.0);
}

#[test]
fn a_faster_sensor_adds_no_cycle_and_the_cycle_waits_for_a_fresh_sample() {
    // Four samples per period, none at a window's opening.
    let mut r = rig(every(T0 + 10_000, P / 4, 4_000));
    let recs = r.run(LOCKED, 900);
    assert_fixed_step(&recs);
    // Every sample that arrived before the last cycle was drained; the newest one is used.
    let pushed = r.bell.seq() as u64;
    let drained = r.counter(&r.shared.stats.sensor_samples);
    assert!(pushed - drained <= 4 && drained > 3_500, "{pushed} pushed, {drained} drained");
    // Until the sensor's period is known (8 intervals), the waiting sample is used at the
    // opening; then each cycle waits for the next arrival, and the grid never moves.
    let s = r.starts();
    assert!(s.open <= 3 && s.arrival >= 897, "{s:?}");
    assert!(latencies(&recs)[3..].iter().all(|&l| l == WRITE_NS));
    let opens: Vec<u64> = recs[3..].iter().map(|rec| (rec.t_ns - T0) % P).collect();
    assert!(opens.iter().all(|&o| o == 10_000), "{:?}", &opens[..8]);
}

#[test]
fn a_slower_sensor_is_locked_onto_and_the_windows_between_run_on_the_schedule() {
    // One sample every other period, arriving after the window (worst phase).
    let mut r = rig(every(T0 + P - 50_000, 2 * P, 700));
    let recs = r.run(LOCKED, 1_200);
    assert_fixed_step(&recs);
    let lat = latencies(&recs);
    assert!(lat.iter().all(|&l| l <= 50_000 + WRITE_NS));
    assert!(lat[lat.len() - 300..].iter().all(|&l| l == WRITE_NS));
    let s = r.starts();
    assert_eq!(s.open + s.arrival + s.fallback, 1_200);
    assert!((599..=601).contains(&s.fallback), "{s:?}");
}

#[test]
fn overruns_skip_whole_windows_and_never_burst() {
    let mut r = rig(every(T0 + P + 450_000, P, 40));
    let cost = r.bus.cost_ns.clone();
    let mut n = 0;
    let (shared, bell) = (r.shared.clone(), r.bell.clone());
    run(&mut r.ctl, &mut r.bus, &mut r.sensor, &shared, &bell, LOCKED, || {
        n += 1;
        // The 15th cycle's write takes 2.5 periods: it starts mid-window 15 (at 15.45 P) and
        // ends at 17.95 P, past the latest start of window 17 (17.9 P).
        cost.set(if n == 15 { 2_500_000 } else { WRITE_NS });
        n <= 20
    });
    assert_eq!(r.counter(&shared.stats.overruns), 2, "windows 16 and 17 were lost");
    let recs: Vec<Record> = std::iter::from_fn(|| r.telemetry.pop().ok()).collect();
    let starts: Vec<u64> = recs[13..].iter().map(|rec| rec.t_ns - T0).collect();
    // Window 18 opens with the sample of 17.45 P waiting, its successor due inside the window:
    // the cycle waits for that one, and arrivals start the cycles again, one per window.
    let expected: Vec<u64> = vec![14_450_000, 15_450_000, 18_450_000, 19_450_000, 20_450_000, 21_450_000, 22_450_000];
    assert_eq!(starts, expected);
}

#[test]
fn waiting_for_samples_allocates_nothing() {
    let mut r = rig(every(T0 + P + 300_000, P / 3, 3_000));
    let arrivals_then_stop = r.sensor.arrivals.len();
    assert!(arrivals_then_stop > 0);
    r.run(LOCKED, 20); // warm up the ring and the telemetry slots
    let (shared, bell) = (r.shared.clone(), r.bell.clone());
    let mut n = 0;
    let before = crate::cycle::tests::counting::count();
    // A faster sensor, then (after ~1000 periods) a stopped one.
    run(&mut r.ctl, &mut r.bus, &mut r.sensor, &shared, &bell, LOCKED, || {
        n += 1;
        n <= 1_200
    });
    assert_eq!(crate::cycle::tests::counting::count() - before, 0, "the runner allocated");
    let s = r.starts();
    assert!(s.arrival > 0 && s.fallback > 0, "both paths ran: {s:?}");
}

#[test]
fn a_stop_during_a_wait_ends_the_loop() {
    let mut r = rig(std::iter::empty());
    let shared = r.shared.clone();
    let bell = r.bell.clone();
    let mut n = 0;
    run(&mut r.ctl, &mut r.bus, &mut r.sensor, &shared, &bell, LOCKED, || {
        n += 1;
        if n == 3 {
            shared.stop.store(true, Ordering::Relaxed);
        }
        true
    });
    assert_eq!(r.counter(&shared.stats.cycles), 2);
}

#[test]
fn after_late_samples_a_jittery_sensor_is_caught_on_arrival_again_at_once() {
    // ±30 % of a period around mid-window, and every 25th sample half a period late on top.
    let arrivals = (0..1_100).map(|k| {
        let late = if k % 25 == 24 { 500_000 } else { 0 };
        (T0 + P + 450_000 + k * P + late).saturating_add_signed(jitter(k, 300_000))
    });
    let mut r = rig(arrivals);
    let recs = r.run(LOCKED, 1_000);
    assert_fixed_step(&recs);
    assert_eq!(r.counter(&r.shared.stats.overruns), 0);
    // A late sample that missed its window waits at most for the next opening (it came within
    // the last tenth of the period); the sample after it is caught on arrival again, never used
    // late at an opening (which would leave every following sample waiting in turn). Rarely,
    // an early sample's successor comes later than the jitter margin: the early one is then
    // used at the end of the wait, at most 1.5 periods after it arrived.
    let lat = latencies(&recs);
    assert!(lat.len() > 950, "{}", lat.len());
    let waited: Vec<u64> = lat.iter().copied().filter(|&l| l > P / 10 + WRITE_NS).collect();
    assert!(waited.len() <= 3 && waited.iter().all(|&l| l <= 3 * P / 2 + WRITE_NS), "{waited:?}");
    let short: Vec<u64> = lat.iter().copied().filter(|&l| l > WRITE_NS && l <= P / 10 + WRITE_NS).collect();
    assert!(short.len() <= 40, "{short:?}");
}

#[test]
fn a_backlog_pushed_in_a_burst_counts_as_one_arrival() {
    // Mid-window arrivals; every 100th period the reader stalls for ten periods, then pushes the
    // ten samples it owes 30 µs apart (each with its own stamp), from 80 % into a period on,
    // across the window's end.
    let arrivals = (0..1_100u64).map(|k| {
        let (stall, j) = (k / 100 * 100 + 50, k % 100);
        if (50..60).contains(&j) {
            T0 + P + (stall + 9) * P + 800_000 + (j - 50) * 30_000
        } else {
            T0 + P + 450_000 + k * P
        }
    });
    let mut r = rig(arrivals);
    let recs = r.run(LOCKED, 1_000);
    assert_fixed_step(&recs);
    // Counted one by one, the burst would make the sensor look 30 µs fast: the next sample that
    // came after its window's cycle would then look long overdue and be used at the opening,
    // and so would every one after it, each waiting half a period, until the estimate recovered.
    let lat = latencies(&recs);
    let waited: Vec<u64> = lat.iter().copied().filter(|&l| l > P / 10 + WRITE_NS).collect();
    assert!(waited.is_empty(), "{waited:?} {:?}", r.starts());
}

#[test]
fn a_faster_sensor_that_drops_samples_still_starts_every_cycle_on_a_fresh_one() {
    // Four samples per period; every 9th never comes (a dropped frame, a reader hiccup).
    let arrivals = (0..4_000u64).filter(|k| k % 9 != 4).map(|k| T0 + 10_000 + k * P / 4);
    let mut r = rig(arrivals);
    let recs = r.run(LOCKED, 900);
    assert_fixed_step(&recs);
    // When the sample a cycle waited for does not come, the next one, also due inside the
    // window, starts it: no cycle falls back on the sample that was waiting at the opening.
    let lat = latencies(&recs);
    assert!(lat[10..].iter().all(|&l| l == WRITE_NS), "{:?}", lat.iter().filter(|&&l| l > WRITE_NS).collect::<Vec<_>>());
    assert_eq!(r.starts().fallback, 0);
}

#[test]
fn a_stalled_faster_sensor_costs_the_waiting_sample_two_of_its_periods_not_the_window() {
    // Four samples per period; every 50 periods the reader stalls for three periods.
    let arrivals = (0..4_000u64).filter(|k| !(188..200).contains(&(k % 200))).map(|k| T0 + 10_000 + k * P / 4);
    let mut r = rig(arrivals);
    let recs = r.run(LOCKED, 900);
    assert_fixed_step(&recs);
    // The sample waiting when the stall began is used 2 sensor periods + the jitter margin
    // after it came (wait through the due arrival and one more); waiting out the whole window
    // would have cost it up to 0.9 period more.
    let lat = latencies(&recs);
    let stalled: Vec<u64> = lat.iter().copied().filter(|&l| l > WRITE_NS).collect();
    assert!(!stalled.is_empty() && stalled.iter().all(|&l| l <= 2 * P / 4 + P / 8 + WRITE_NS), "{stalled:?}");
}

#[test]
fn a_sensor_on_another_clock_drags_the_grid_and_the_model_keeps_whole_steps_within_half_a_period() {
    // A sensor at the loop's rate by its own clock, 0.15 % slow or fast against the host's: the
    // phase lock follows it, so the grid drifts by two periods over 1300 cycles. The model's
    // time (whole steps, `deadline_ns`) stays within half a period of the grid: a cycle of two
    // steps when the stretched grid has run half a period ahead, of none when it fell behind.
    for (interval, repeats, doubles) in [(P + 1_500, 0, 2), (P - 1_500, 2, 0)] {
        let mut r = rig(every(T0 + P + 450_000, interval, 1_400));
        let recs = r.run(LOCKED, 1_300);
        assert_eq!(r.starts().arrival, 1_300, "every cycle on its sample's arrival");
        assert!(recs.windows(2).all(|w| (w[1].deadline_ns - w[0].deadline_ns) % P == 0), "whole steps");
        let steps: Vec<u64> = recs.windows(2).map(|w| (w[1].deadline_ns - w[0].deadline_ns) / P).collect();
        assert_eq!((steps.iter().filter(|&&s| s == 0).count(), steps.iter().filter(|&&s| s == 2).count()), (repeats, doubles));
        // The grid point of each cycle: its start (the arrival) less the lock's mid-window phase,
        // which trails a drifting sensor by 12 µs (the drift per cycle over the lock's gain of 1/8).
        let worst = recs.iter().map(|rec| (rec.deadline_ns as i64 - (rec.t_ns as i64 - 450_000)).abs()).max().unwrap();
        assert!(worst <= (P / 2 + 15_000) as i64, "{worst} ns from the grid");
        // θ is the model's after as many steps as its time says: a·h²·n(n+1)/2.
        let (h, a) = (P as f64 / 1e9, FX * 0.1 / 0.02);
        for rec in &recs {
            let n = ((rec.deadline_ns - recs[0].deadline_ns) / P + 1) as f64;
            let theta = a * h * h * n * (n + 1.0) / 2.0;
            assert!((rec.theta - theta).abs() < 1e-9 * theta.max(1.0), "θ {} vs {theta} after {n} steps", rec.theta);
        }
    }
}
