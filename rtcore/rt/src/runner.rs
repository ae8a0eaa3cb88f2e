//! The paced loop: sleep to the next absolute deadline, run the cycle, repeat until stopped.
//!
//! Kept apart from the cycle so the pacing (overruns skipped and counted, never caught up) is
//! tested with a fake clock and a slow in-memory bus, and the cycle without any clock at all.
use crate::bus::Transport;
use crate::clock::{Clock, Pacer};
use crate::cycle::Controller;
use crate::shared::Shared;
use crate::telemetry::LoopStats;
use std::sync::atomic::Ordering;

/// Runs cycles on the grid `start + k·period` until `shared.stop` is set or `keep_going`
/// returns false (checked before each sleep).
pub fn run<C: Clock>(
    ctl: &mut Controller,
    t: &mut dyn Transport,
    clock: &mut C,
    shared: &Shared,
    mut keep_going: impl FnMut() -> bool,
) {
    let start_ns = clock.now_ns();
    ctl.begin(start_ns);
    let mut pacer = Pacer::new(start_ns, ctl.period_ns());
    while !shared.stop.load(Ordering::Relaxed) && keep_going() {
        let missed = pacer.skip_missed(clock.now_ns());
        if missed > 0 {
            LoopStats::add(&shared.stats.overruns, missed);
        }
        clock.sleep_until(pacer.next_deadline_ns());
        ctl.run_cycle(t, clock, pacer.next_deadline_ns());
        pacer.advance();
    }
}
