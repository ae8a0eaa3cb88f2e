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
//! The clock is a trait so that the deadline arithmetic and the overrun accounting can be tested
//! against a fake clock, deterministically, without timed assertions.

/// A monotonic time source the loop can sleep on.
pub trait Clock {
    /// Nanoseconds on the clock's monotonic time line.
    fn now_ns(&self) -> u64;
    /// Sleeps until `deadline_ns` has passed (returns at once if it already has).
    fn sleep_until(&mut self, deadline_ns: u64);
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
}

/// The grid of cycle deadlines `start + k·period`, with overrun skipping.
#[derive(Debug, Clone)]
pub struct Pacer {
    period_ns: u64,
    next_ns: u64,
}

impl Pacer {
    /// The first deadline is one period after `start_ns`.
    pub fn new(start_ns: u64, period_ns: u64) -> Self {
        let period_ns = period_ns.max(1);
        Pacer { period_ns, next_ns: start_ns + period_ns }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The deadline the loop sleeps until next.
    pub fn next_deadline_ns(&self) -> u64 {
        self.next_ns
    }

    /// Called before sleeping: if `now_ns` is already past the next deadline, skips every
    /// deadline that has passed and returns how many were missed (the overruns).
    pub fn skip_missed(&mut self, now_ns: u64) -> u64 {
        if now_ns <= self.next_ns {
            return 0;
        }
        let missed = (now_ns - self.next_ns) / self.period_ns + 1;
        self.next_ns += missed * self.period_ns;
        missed
    }

    /// Called after the cycle of the current deadline ran: moves to the following one.
    pub fn advance(&mut self) {
        self.next_ns += self.period_ns;
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
