//! The paced loop: wait for the cycle's start (a deadline, or a force sample inside the
//! period's window, see [`crate::trigger`]), run the cycle, repeat until stopped.
//!
//! Kept apart from the cycle so the pacing (overruns skipped and counted, never caught up; one
//! cycle per window whatever the sensor does) is tested with a fake clock, a scripted sensor and
//! a slow in-memory bus, and the cycle without any clock at all.
use crate::bus::Transport;
use crate::clock::Clock;
use crate::cycle::Controller;
use crate::doorbell::Doorbell;
use crate::shared::Shared;
use crate::telemetry::LoopStats;
use crate::trigger::{Start, Step, Trigger, TriggerMode};
use std::sync::atomic::Ordering;

/// Runs one cycle per window of the grid `start + k·period` until `shared.stop` is set or
/// `keep_going` returns false (checked before each wait).
pub fn run<C: Clock>(
    ctl: &mut Controller,
    t: &mut dyn Transport,
    clock: &mut C,
    shared: &Shared,
    bell: &Doorbell,
    mode: TriggerMode,
    mut keep_going: impl FnMut() -> bool,
) {
    let start_ns = clock.now_ns();
    ctl.begin(start_ns);
    let mut trigger = Trigger::new(mode, start_ns, ctl.period_ns());
    while !stopped(shared) && keep_going() {
        let missed = trigger.skip_missed(clock.now_ns());
        if missed > 0 {
            LoopStats::add(&shared.stats.overruns, missed);
        }
        let Some(start) = await_start(&trigger, clock, shared, bell) else { break };
        let drained_before = drained(shared);
        // The model counts its steps against the (phase-locked) grid point, never the start: a
        // start anywhere in the window is still one step.
        ctl.run_cycle(t, clock, trigger.open_ns(), start.due_ns);
        let timing = bell.timing();
        trigger.after_cycle(drained(shared) != drained_before, &timing);
        shared.trigger.record(start.cause, &trigger, &timing);
    }
}

/// Sleeps until the window opens, then until the cycle may start; `None` when stopped.
fn await_start<C: Clock>(trigger: &Trigger, clock: &mut C, shared: &Shared, bell: &Doorbell) -> Option<Start> {
    clock.sleep_until(trigger.open_ns());
    // Read the count before judging what waits, so a push from now on changes it and is seen.
    let seq = bell.seq();
    let (until_ns, otherwise) = match trigger.plan(pending(seq, shared), &bell.timing()) {
        Step::Run(start) => return Some(start),
        Step::Wait { until_ns, otherwise } => (until_ns, otherwise),
    };
    loop {
        if stopped(shared) {
            return None;
        }
        if bell.seq() != seq {
            return Some(trigger.arrival_start(&bell.timing()));
        }
        if clock.now_ns() >= until_ns {
            return Some(otherwise);
        }
        clock.wait_for_ring(bell, seq, until_ns);
    }
}

/// Samples the cycles have taken from the ring so far (wrapping like the bell's count).
fn drained(shared: &Shared) -> u32 {
    shared.stats.sensor_samples.load(Ordering::Relaxed) as u32
}

/// A sample was pushed that no cycle has drained yet.
fn pending(seq: u32, shared: &Shared) -> bool {
    // Signed: a sample drained in the instant between its push and its count is not "owed".
    (seq.wrapping_sub(drained(shared)) as i32) > 0
}

fn stopped(shared: &Shared) -> bool {
    shared.stop.load(Ordering::Relaxed)
}

#[cfg(test)]
#[path = "runner_tests.rs"]
mod tests;
