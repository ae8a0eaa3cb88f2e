//! The loop's clock and its absolute-deadline pacer.
//!
//! Why absolute deadlines: a relative `sleep(period)` adds the wake-up latency and the cycle's
//! own work to every period, so the loop drifts (+6…19 % measured on the dev VM). Sleeping until
//! `start + k·period` on CLOCK_MONOTONIC keeps the grid fixed whatever each cycle costs.
//!
//! Why skip, not catch up: after an overrun the missed deadlines are in the past. Running them
//! back to back would burst SyncWrites onto the bus with stale timing; like ros2_control we count
//! them and jump to the next deadline still in the future (`next += k·period`).
//!
//! Why a window: a cycle may start when a force sample arrives (see [`crate::trigger`]), so each
//! period of the grid is a window `[open, open + window]` in which its one cycle runs; the
//! schedule-only loop is the special case of a zero-width window. A missed window is one whose
//! latest start (`open + window`) has passed.
//!
//! The clock is a trait so that the deadline arithmetic, the overrun accounting and the
//! sample-triggered starts can be tested against a fake clock (with a scripted sensor),
//! deterministically, without timed assertions.
use crate::doorbell::Doorbell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// A monotonic time source the loop can sleep on.
pub trait Clock {
    /// Nanoseconds on the clock's monotonic time line.
    fn now_ns(&self) -> u64;
    /// Sleeps until `deadline_ns` has passed (returns at once if it already has).
    fn sleep_until(&mut self, deadline_ns: u64);
    /// Sleeps until `bell.seq()` differs from `seq` (a sample was pushed) or `deadline_ns`
    /// passes. May return early; the caller re-checks.
    fn wait_for_ring(&mut self, bell: &Doorbell, seq: u32, deadline_ns: u64);
}

/// CLOCK_MONOTONIC: the clock Python's `time.monotonic_ns()` reads, so force samples stamped in
/// Python and the loop's own times share one time line.
#[derive(Debug, Default, Clone, Copy)]
pub struct MonotonicClock;

/// `clock_gettime(CLOCK_MONOTONIC)` in nanoseconds.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        monotonic_ns()
    }

    fn sleep_until(&mut self, deadline_ns: u64) {
        let ts = libc::timespec {
            tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
            tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
        };
        loop {
            // SAFETY: `ts` is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
            let rc = unsafe {
                libc::clock_nanosleep(
                    libc::CLOCK_MONOTONIC,
                    libc::TIMER_ABSTIME,
                    &ts,
                    std::ptr::null_mut(),
                )
            };
            // A signal interrupts the sleep; the deadline is absolute, so retry it unchanged.
            if rc != libc::EINTR {
                break;
            }
        }
    }

    fn wait_for_ring(&mut self, bell: &Doorbell, seq: u32, deadline_ns: u64) {
        bell.wait(seq, deadline_ns);
    }
}

/// A simulated monotonic clock that moves only when told to, shared by its clones across
/// threads (unlike the tests' `FakeClock`, it is `Send`): the lockstep mock's model time
/// (`dxlsim::lockstep`, where the link's waits move it) and a test bus whose packets cost time
/// (`cycle_busy_bus_tests`). Sleeping moves it to the deadline; it never goes back.
#[derive(Debug, Clone, Default)]
pub struct SharedClock(Arc<AtomicU64>);

impl SharedClock {
    /// Moves the clock on to `ns` (no-op if it is already there or later).
    pub fn advance_to(&self, ns: u64) {
        self.0.fetch_max(ns, Ordering::Relaxed);
    }
}

impl Clock for SharedClock {
    fn now_ns(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }

    fn sleep_until(&mut self, deadline_ns: u64) {
        self.advance_to(deadline_ns);
    }

    fn wait_for_ring(&mut self, _bell: &Doorbell, _seq: u32, deadline_ns: u64) {
        self.advance_to(deadline_ns);
    }
}

/// The grid of cycle windows `start + k·period`, with overrun skipping and a bounded phase shift.
#[derive(Debug, Clone)]
pub struct Pacer {
    period_ns: u64,
    window_ns: u64,
    next_ns: u64,
}

impl Pacer {
    /// Zero-width windows: the first deadline is one period after `start_ns`.
    pub fn new(start_ns: u64, period_ns: u64) -> Self {
        Self::with_window(start_ns, period_ns, 0)
    }

    /// Windows `window_ns` wide (clamped below one period), the first opening one period after
    /// `start_ns`.
    pub fn with_window(start_ns: u64, period_ns: u64, window_ns: u64) -> Self {
        let period_ns = period_ns.max(1);
        Pacer { period_ns, window_ns: window_ns.min(period_ns - 1), next_ns: start_ns + period_ns }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    pub fn window_ns(&self) -> u64 {
        self.window_ns
    }

    /// When the next window opens: the deadline a schedule-only loop sleeps until.
    pub fn next_deadline_ns(&self) -> u64 {
        self.next_ns
    }

    /// The latest start of the next window's cycle.
    pub fn fallback_ns(&self) -> u64 {
        self.next_ns + self.window_ns
    }

    /// Called before waiting: if `now_ns` is already past the next window's latest start, skips
    /// every window that has passed and returns how many were missed (the overruns).
    pub fn skip_missed(&mut self, now_ns: u64) -> u64 {
        if now_ns <= self.fallback_ns() {
            return 0;
        }
        let missed = (now_ns - self.fallback_ns()) / self.period_ns + 1;
        self.next_ns += missed * self.period_ns;
        missed
    }

    /// Called after the cycle of the current window ran: moves to the following one.
    pub fn advance(&mut self) {
        self.next_ns += self.period_ns;
    }

    /// Moves the grid by `delta_ns` (the phase lock's correction), never before `not_before_ns`.
    pub fn shift(&mut self, delta_ns: i64, not_before_ns: u64) {
        self.next_ns = self.next_ns.saturating_add_signed(delta_ns).max(not_before_ns);
    }
}

#[cfg(test)]
pub(crate) mod fake {
    use super::Clock;
    use std::cell::Cell;
    use std::rc::Rc;

    /// A clock that only moves when told: sleeping jumps to the deadline plus a fixed wake-up
    /// latency; work is simulated with `advance`.
    #[derive(Clone)]
    pub struct FakeClock {
        pub now: Rc<Cell<u64>>,
        pub wake_latency_ns: u64,
    }

    impl FakeClock {
        pub fn new(start_ns: u64, wake_latency_ns: u64) -> Self {
            FakeClock { now: Rc::new(Cell::new(start_ns)), wake_latency_ns }
        }
        pub fn advance(&self, ns: u64) {
            self.now.set(self.now.get() + ns);
        }
    }

    impl Clock for FakeClock {
        fn now_ns(&self) -> u64 {
            self.now.get()
        }
        fn sleep_until(&mut self, deadline_ns: u64) {
            if deadline_ns > self.now.get() {
                self.now.set(deadline_ns + self.wake_latency_ns);
            }
        }
        /// No sensor behind this clock: nothing rings, so the wait lasts to its deadline.
        fn wait_for_ring(&mut self, _bell: &super::Doorbell, _seq: u32, deadline_ns: u64) {
            self.sleep_until(deadline_ns);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::fake::FakeClock;
    use super::*;

    #[test]
    fn deadlines_stay_on_the_grid_whatever_the_work_costs() {
        let mut clock = FakeClock::new(1_000, 7);
        let mut pacer = Pacer::new(1_000, 100);
        for k in 1..=50u64 {
            assert_eq!(pacer.skip_missed(clock.now_ns()), 0);
            assert_eq!(pacer.next_deadline_ns(), 1_000 + k * 100);
            clock.sleep_until(pacer.next_deadline_ns());
            clock.advance(k % 60); // work shorter than the period, varying
            pacer.advance();
        }
    }

    #[test]
    fn an_overrun_skips_the_missed_deadlines_without_catching_up() {
        let mut pacer = Pacer::new(0, 100);
        // The cycle of deadline 100 ran until t = 351: deadlines 200 and 300 are lost.
        pacer.advance();
        assert_eq!(pacer.next_deadline_ns(), 200);
        assert_eq!(pacer.skip_missed(351), 2);
        assert_eq!(pacer.next_deadline_ns(), 400);
        // Exactly on a deadline is not late.
        pacer.advance();
        assert_eq!(pacer.skip_missed(500), 0);
    }

    #[test]
    fn real_sleep_never_wakes_before_its_deadline() {
        let mut clock = MonotonicClock;
        let deadline = clock.now_ns() + 200_000;
        clock.sleep_until(deadline);
        assert!(clock.now_ns() >= deadline);
    }

    #[test]
    fn a_window_is_missed_only_once_its_latest_start_has_passed() {
        let mut pacer = Pacer::with_window(0, 100, 90);
        assert_eq!((pacer.next_deadline_ns(), pacer.fallback_ns()), (100, 190));
        assert_eq!(pacer.skip_missed(190), 0, "late within the window is not an overrun");
        assert_eq!(pacer.skip_missed(191), 1);
        assert_eq!((pacer.next_deadline_ns(), pacer.fallback_ns()), (200, 290));
        // A window can never reach the next one: at least one period minus the window between.
        assert_eq!(Pacer::with_window(0, 100, 500).window_ns(), 99);
    }

    #[test]
    fn a_phase_shift_moves_the_grid_but_never_into_the_past() {
        let mut pacer = Pacer::with_window(0, 100, 90);
        pacer.shift(-7, 0);
        assert_eq!(pacer.next_deadline_ns(), 93);
        pacer.shift(-50, 60);
        assert_eq!(pacer.next_deadline_ns(), 60);
        pacer.advance();
        assert_eq!(pacer.next_deadline_ns(), 160);
    }

    proptest::proptest! {
        #[test]
        fn skipping_lands_on_the_first_future_grid_point(period in 1u64..10_000, late in 0u64..1_000_000) {
            let mut pacer = Pacer::new(0, period);
            let now = period + late;
            let missed = pacer.skip_missed(now);
            let next = pacer.next_deadline_ns();
            proptest::prop_assert_eq!(next % period, 0);
            proptest::prop_assert!(next > now && next <= now + period);
            proptest::prop_assert_eq!(next, period * (1 + missed));
        }
    }
}
