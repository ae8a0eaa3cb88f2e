//! When a cycle starts: on a fixed schedule, or as soon as a force sample arrives.
//!
//! Why: on a fixed schedule a sample waits for the next deadline, on average half a period and
//! up to a whole one, before any cycle uses it (bench/loop_timing.py measured the force→write
//! latency of the Rust loop equal to a Python loop's). Starting the cycle when the sample
//! arrives removes that wait.
//!
//! What stays fixed: the model integrates exactly h = 1/rate per cycle, so cycles must keep to
//! one per period. The grid of periods stays ([`Pacer`]); each period is a *window*
//! `[open, open + 0.9·period]` holding exactly one cycle, which starts:
//! - at the window's opening if a sample arrived since the last cycle (it waited in the ring);
//! - else at the first sample arrival inside the window (the sink's push wakes the thread);
//! - else at the window's end, on the schedule (a late or stopped sensor: the stale rule of
//!   [`crate::sensor`] then holds the joints as before).
//!
//! Two refinements, both measured in bench/loop_timing.py:
//! - *Waiting for a newer sample.* A sample can be waiting at the opening because it came
//!   after the previous cycle had started (a sensor faster than the loop always leaves one; a
//!   sensor at the loop's rate does after one late sample). If a newer one is due inside the
//!   window (from the measured arrival period), the cycle waits for an arrival: through that
//!   one and one more missed arrival, at most to the window's end. Otherwise a fast sensor's
//!   samples would be used up to one sensor period old, and after one late sample every
//!   following sample would wait for the next opening in turn.
//! - *The phase lock.* A sensor at the loop's rate (or a divisor of it) arrives at a fixed phase
//!   of the grid. If that phase fell in the last tenth of the period (after the window), every
//!   sample would wait for the next opening. The lock nudges the grid, by at most period/500 per
//!   cycle, until arrivals land mid-window. The cycle rate then stays within 0.2 % of `rate_hz`,
//!   and equals it on average when the sensor shares the loop's clock.
//!
//! Two cycles are never closer than a tenth of a period (a window's end to the next opening);
//! a sensor faster than the loop never adds cycles: its extra samples are drained, the newest
//! used, as on the schedule.
use crate::clock::Pacer;
use crate::doorbell::ArrivalTiming;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering::Relaxed};

/// The window's share of the period, in tenths: 9 leaves a tenth of the period between a cycle
/// at a window's end and one at the next opening.
const WINDOW_TENTHS: u64 = 9;
/// The phase lock moves the grid by at most period / SLEW_DIVISOR per cycle.
const SLEW_DIVISOR: i64 = 500;
/// The phase lock corrects 1/GAIN_DIVISOR of the phase error per cycle (before the slew limit).
const GAIN_DIVISOR: i64 = 8;
/// The reported phase error is an average over about this many measurements.
const PHASE_ERROR_SMOOTHING: i64 = 16;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TriggerMode {
    /// Every cycle on the fixed grid `start + k·period` (zero-width windows).
    Schedule,
    /// A cycle per window, started by a sample's arrival; `phase_lock` moves the grid onto a
    /// sensor running at the loop's rate.
    Sample { phase_lock: bool },
}

impl Default for TriggerMode {
    fn default() -> Self {
        TriggerMode::Sample { phase_lock: true }
    }
}

impl TriggerMode {
    pub fn name(&self) -> &'static str {
        match self {
            TriggerMode::Schedule => "schedule",
            TriggerMode::Sample { .. } => "sample",
        }
    }
}

/// Why a cycle started.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cause {
    /// The fixed grid (schedule mode).
    Schedule = 0,
    /// A sample was already waiting when the window opened, and none newer was due in it.
    Open = 1,
    /// A sample arrived inside the window.
    Arrival = 2,
    /// No (newer) sample came: the window's end.
    Fallback = 3,
}

/// A cycle's start: the moment it was due (its period error is measured from there) and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Start {
    pub due_ns: u64,
    pub cause: Cause,
}

/// What to do at a window's opening.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    Run(Start),
    /// Wait for a sample until `until_ns`; if none comes, start as `otherwise`.
    Wait { until_ns: u64, otherwise: Start },
}

pub struct Trigger {
    mode: TriggerMode,
    pacer: Pacer,
    /// Where in the window the phase lock puts the arrivals: its middle.
    target_ns: i64,
    slew_ns: i64,
    /// The phase error the lock measured (arrival − target), smoothed, for the statistics.
    pub phase_error_ns: i64,
}

impl Trigger {
    pub fn new(mode: TriggerMode, start_ns: u64, period_ns: u64) -> Self {
        let window_ns = match mode {
            TriggerMode::Schedule => 0,
            TriggerMode::Sample { .. } => period_ns * WINDOW_TENTHS / 10,
        };
        let pacer = Pacer::with_window(start_ns, period_ns, window_ns);
        Trigger {
            mode,
            target_ns: (pacer.window_ns() / 2) as i64,
            slew_ns: (pacer.period_ns() as i64 / SLEW_DIVISOR).max(1),
            pacer,
            phase_error_ns: 0,
        }
    }

    pub fn mode(&self) -> TriggerMode {
        self.mode
    }

    pub fn open_ns(&self) -> u64 {
        self.pacer.next_deadline_ns()
    }

    pub fn fallback_ns(&self) -> u64 {
        self.pacer.fallback_ns()
    }

    /// Skips the windows whose latest start has passed; returns how many (the overruns).
    pub fn skip_missed(&mut self, now_ns: u64) -> u64 {
        self.pacer.skip_missed(now_ns)
    }

    /// The decision at the window's opening, given whether a sample is waiting in the ring.
    pub fn plan(&self, pending: bool, timing: &ArrivalTiming) -> Step {
        let open = self.open_ns();
        if self.mode == TriggerMode::Schedule {
            return Step::Run(Start { due_ns: open, cause: Cause::Schedule });
        }
        let fallback = self.fallback_ns();
        let until_ns = if pending {
            match self.newer_sample_due(timing) {
                Some(until_ns) => until_ns,
                None => return Step::Run(Start { due_ns: open, cause: Cause::Open }),
            }
        } else {
            fallback
        };
        Step::Wait { until_ns, otherwise: Start { due_ns: until_ns, cause: Cause::Fallback } }
    }

    /// The start of a cycle woken by an arrival: due when the sample was pushed (not before
    /// the window opened).
    pub fn arrival_start(&self, timing: &ArrivalTiming) -> Start {
        Start { due_ns: timing.last_ns.max(self.open_ns()), cause: Cause::Arrival }
    }

    /// With a sample waiting at the opening: if a newer one is due inside this window, how long
    /// to wait for an arrival; `None` to use the waiting sample now. Until the sensor's period
    /// is known, it is taken to be the loop's.
    fn newer_sample_due(&self, timing: &ArrivalTiming) -> Option<u64> {
        let interval = if timing.interval_ns > 0 { timing.interval_ns } else { self.pacer.period_ns() }.max(1);
        // A margin for jitter: an eighth of the period plus twice the measured jitter, at most
        // half the period.
        let margin = interval / 8 + (2 * timing.spread_ns).min(interval * 3 / 8);
        // The next arrival still to come: arrivals due more than the margin before the opening
        // are counted as missed (a dropped frame, a stalled reader).
        let overdue = self.open_ns().saturating_sub(timing.last_ns.saturating_add(margin));
        let due = timing.last_ns.saturating_add((overdue.div_ceil(interval)).max(1).saturating_mul(interval));
        let fallback = self.fallback_ns();
        // Wait through one more missed arrival (the one after may come), then give the waiting
        // sample up: a stalled sensor costs it at most two periods and the margin, not the
        // whole window.
        (due <= fallback).then(|| due.saturating_add(interval).saturating_add(margin).min(fallback))
    }

    /// After the window's cycle: moves to the next window, nudged by the phase lock when this
    /// cycle used a new sample from a sensor no faster than the loop.
    pub fn after_cycle(&mut self, used_new_sample: bool, timing: &ArrivalTiming) {
        let open = self.open_ns();
        let period = self.pacer.period_ns();
        self.pacer.advance();
        let locking = matches!(self.mode, TriggerMode::Sample { phase_lock: true });
        // A sensor faster than the loop has an arrival in every window anyway (the refinement
        // above): locking onto one of several arrivals per period would only chase them.
        let sensor_not_faster = timing.interval_ns >= period * WINDOW_TENTHS / 10;
        if !(locking && used_new_sample && sensor_not_faster && timing.last_ns > 0) {
            return;
        }
        // Not wrapped around the period: a sample that waited for this opening (negative
        // phase) always moves the grid earlier, onto the arrival, so the cycle starts on the
        // next one; the other way round it would keep starting at the opening, on a sample
        // that waits longer and longer, until the grid had moved by half a period.
        let error = timing.last_ns as i64 - open as i64 - self.target_ns;
        self.phase_error_ns += (error - self.phase_error_ns) / PHASE_ERROR_SMOOTHING;
        // max/min, not clamp: the RT thread never calls what can panic (slew_ns ≥ 1 anyway).
        let delta = (error / GAIN_DIVISOR).max(-self.slew_ns).min(self.slew_ns);
        self.pacer.shift(delta, open + period / 2);
    }
}

/// How the loop's cycles started, for `stats()["trigger"]`.
#[derive(Default)]
pub struct TriggerStats {
    starts: [AtomicU64; 4],
    phase_error_ns: AtomicI64,
    sensor_interval_ns: AtomicU64,
    sensor_jitter_ns: AtomicU64,
}

/// A copy of [`TriggerStats`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TriggerSnapshot {
    pub schedule: u64,
    pub open: u64,
    pub arrival: u64,
    pub fallback: u64,
    pub phase_error_us: f64,
    pub sensor_interval_us: f64,
    pub sensor_jitter_us: f64,
}

impl TriggerStats {
    pub fn record(&self, cause: Cause, trigger: &Trigger, timing: &ArrivalTiming) {
        self.starts[cause as usize].fetch_add(1, Relaxed);
        self.phase_error_ns.store(trigger.phase_error_ns, Relaxed);
        self.sensor_interval_ns.store(timing.interval_ns, Relaxed);
        self.sensor_jitter_ns.store(timing.spread_ns, Relaxed);
    }

    pub fn snapshot(&self) -> TriggerSnapshot {
        let n = |c: Cause| self.starts[c as usize].load(Relaxed);
        TriggerSnapshot {
            schedule: n(Cause::Schedule),
            open: n(Cause::Open),
            arrival: n(Cause::Arrival),
            fallback: n(Cause::Fallback),
            phase_error_us: self.phase_error_ns.load(Relaxed) as f64 / 1e3,
            sensor_interval_us: self.sensor_interval_ns.load(Relaxed) as f64 / 1e3,
            sensor_jitter_us: self.sensor_jitter_ns.load(Relaxed) as f64 / 1e3,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: u64 = 1_000_000;

    fn timing(last_ns: u64, interval_ns: u64) -> ArrivalTiming {
        ArrivalTiming { last_ns, interval_ns, spread_ns: 0 }
    }

    #[test]
    fn schedule_mode_runs_at_each_opening() {
        let t = Trigger::new(TriggerMode::Schedule, 0, P);
        assert_eq!(t.plan(true, &timing(0, 0)), Step::Run(Start { due_ns: P, cause: Cause::Schedule }));
        assert_eq!(t.fallback_ns(), P, "a zero-width window");
    }

    #[test]
    fn with_nothing_waiting_the_cycle_waits_for_a_sample_until_the_windows_end() {
        let t = Trigger::new(TriggerMode::default(), 0, P);
        let end = P + 900_000;
        assert_eq!(t.plan(false, &timing(0, 0)), Step::Wait { until_ns: end, otherwise: Start { due_ns: end, cause: Cause::Fallback } });
        assert_eq!(t.arrival_start(&timing(P + 300, P)), Start { due_ns: P + 300, cause: Cause::Arrival });
    }

    #[test]
    fn a_waiting_sample_runs_at_once_unless_a_newer_one_is_due_inside_the_window() {
        let t = Trigger::new(TriggerMode::default(), 0, P);
        let now = Step::Run(Start { due_ns: P, cause: Cause::Open });
        let wait = |until_ns| Step::Wait { until_ns, otherwise: Start { due_ns: until_ns, cause: Cause::Fallback } };
        // Sensor at the loop's rate, its sample 1 % of a period old: the next falls after the
        // window; the same while the period is not known (the loop's is assumed).
        assert_eq!(t.plan(true, &timing(P - 10_000, P)), now);
        assert_eq!(t.plan(true, &timing(P - 10_000, 0)), now);
        // Its sample 55 % old (it came after the last cycle had started): the next is due 45 %
        // into the window; wait for an arrival, up to the window's end.
        assert_eq!(t.plan(true, &timing(P - 550_000, P)), wait(P + 900_000));
        assert_eq!(t.plan(true, &timing(P - 550_000, 0)), wait(P + 900_000));
        // A 4x faster sensor: the next is due 150 µs in; wait through it and one more (and the
        // margin, 31 µs): the waiting sample is given up 2.125 sensor periods after it came.
        assert_eq!(t.plan(true, &timing(P - 100_000, 250_000)), wait(P + 400_000 + 31_250));
        // Two samples missed (due 400 and 150 µs before the opening): the next is due 100 µs in.
        assert_eq!(t.plan(true, &timing(P - 650_000, 250_000)), wait(P + 350_000 + 31_250));
        // A sensor at the loop's rate, its sample due at the opening not there yet (late by less
        // than the jitter margin): wait for it.
        assert_eq!(t.plan(true, &timing(0, P)), wait(P + 900_000));
        // Its sample due 0.2 period before the opening missed (by more than the margin): the one
        // after it is due 0.8 period in; wait for that.
        let later = Trigger::new(TriggerMode::default(), 10 * P, P);
        let missed = ArrivalTiming { last_ns: 11 * P - 1_200_000, interval_ns: P, spread_ns: 0 };
        let end = 11 * P + 900_000;
        assert_eq!(later.plan(true, &missed), Step::Wait { until_ns: end, otherwise: Start { due_ns: end, cause: Cause::Fallback } });
    }

    #[test]
    fn the_phase_lock_moves_the_grid_towards_mid_window_by_a_bounded_step() {
        let mut t = Trigger::new(TriggerMode::default(), 0, P);
        // A sample that arrived after the previous window (at 95 % of the period) and waited
        // for this opening: the grid moves earlier, onto it, by the most it may in one cycle.
        let open = t.open_ns();
        t.after_cycle(true, &timing(open - 50_000, P));
        assert_eq!(t.open_ns(), open + P - 2_000);
        assert_eq!(t.phase_error_ns, -500_000 / 16, "reported smoothed");
        // A small error is corrected by an eighth.
        let open = t.open_ns();
        t.after_cycle(true, &timing(open + 450_000 + 800, P));
        assert_eq!(t.open_ns(), open + P + 100);
        // No new sample, no lock off, a faster sensor: the grid keeps its period.
        for (used, mode, interval) in [(false, TriggerMode::default(), P), (true, TriggerMode::Sample { phase_lock: false }, P), (true, TriggerMode::default(), P / 4)] {
            let mut t = Trigger::new(mode, 0, P);
            let open = t.open_ns();
            t.after_cycle(used, &timing(open + 10, interval));
            assert_eq!(t.open_ns(), open + P);
        }
    }
}
