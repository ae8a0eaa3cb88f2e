//! How the force sink tells the loop thread that a sample arrived, and what the loop knows of
//! the sensor's timing.
//!
//! Why a futex: the loop thread must sleep until "a sample arrives or this absolute deadline
//! passes", whichever comes first. `FUTEX_WAIT_BITSET` does exactly that in one syscall, on a
//! CLOCK_MONOTONIC absolute deadline (no drift), with no file descriptor and no allocation. The
//! pusher issues `FUTEX_WAKE` only while the loop is *armed* (waiting for a sample inside its
//! window), so a sensor faster than the loop costs one wake-up per cycle, not one per sample.
//!
//! Why push times and not the samples' own stamps drive the trigger: a reader stamps a sample
//! when it reads it and may push it a little later; the loop can only act once it is pushed.
//! The stamps still define the latency (contract `latency_us`); the push times define when a
//! cycle can start and what the sensor's period is.
//!
//! Why bursts count as one arrival: a reader that gets several frames in one read pushes them
//! back to back, and one that stalled pushes its backlog in a burst. For the trigger that is one
//! arrival: the first push wakes the loop, the others are drained with it. Counted one by one,
//! a burst would make the sensor look many times faster than it is.
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering::*};

/// A push closer than this to the previous push belongs to the same arrival (a burst).
const BURST_GAP_NS: u64 = 50_000;
/// Intervals before the period estimate is trusted.
const WARM_UP_INTERVALS: u32 = 8;
/// EWMA weight of a new interval (1/8: a few periods to follow a rate change, smooth enough to
/// ignore one late sample).
const EWMA: f64 = 0.125;

/// The sensor's timing as the loop sees it: all CLOCK_MONOTONIC push times.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ArrivalTiming {
    /// The first push of the newest arrival (0 before any).
    pub last_ns: u64,
    /// Estimated time between arrivals; 0 while unknown.
    pub interval_ns: u64,
    /// Mean absolute deviation of the intervals from the estimate (the arrival jitter).
    pub spread_ns: u64,
}

/// Turns pushes into arrivals and estimates the arrival period. Lives on the sink's side (its
/// state is behind the sink's mutex), publishes through the [`Doorbell`].
#[derive(Debug, Default, Clone)]
pub struct ArrivalEstimator {
    /// Any push seen yet.
    started: bool,
    /// The newest push, and the first push of the newest arrival.
    last_push_ns: u64,
    arrival_ns: u64,
    mean: f64,
    spread: f64,
    intervals: u32,
}

impl ArrivalEstimator {
    /// Feeds one successful push at `push_ns`; returns the new timing when it starts a new
    /// arrival.
    pub fn observe(&mut self, push_ns: u64) -> Option<ArrivalTiming> {
        let in_burst = self.started && push_ns.saturating_sub(self.last_push_ns) < BURST_GAP_NS;
        self.last_push_ns = push_ns;
        if in_burst {
            return None;
        }
        if self.started {
            self.add_interval(push_ns.saturating_sub(self.arrival_ns) as f64);
        }
        self.started = true;
        self.arrival_ns = push_ns;
        Some(self.timing())
    }

    fn add_interval(&mut self, x: f64) {
        if self.intervals == 0 {
            self.mean = x;
        } else {
            // A pause (the sensor stalled) counts as at most 4 periods, so one gap cannot throw
            // the estimate far off, yet a real rate change is followed within some twenty arrivals.
            let x = x.min(4.0 * self.mean);
            self.spread += EWMA * ((x - self.mean).abs() - self.spread);
            self.mean += EWMA * (x - self.mean);
        }
        self.intervals = self.intervals.saturating_add(1);
    }

    pub fn timing(&self) -> ArrivalTiming {
        let known = self.intervals >= WARM_UP_INTERVALS;
        ArrivalTiming {
            last_ns: self.arrival_ns,
            interval_ns: if known { self.mean as u64 } else { 0 },
            spread_ns: if known { self.spread as u64 } else { 0 },
        }
    }
}

/// The sink rings, the loop thread waits. All fields are atomics: the loop never locks.
#[derive(Debug, Default)]
pub struct Doorbell {
    /// Successful pushes so far (wrapping): the futex word.
    seq: AtomicU32,
    /// The loop thread is waiting (or about to wait) on `seq`.
    armed: AtomicBool,
    last_ns: AtomicU64,
    interval_ns: AtomicU64,
    spread_ns: AtomicU64,
}

impl Doorbell {
    /// Successful pushes so far, wrapping at 2³².
    pub fn seq(&self) -> u32 {
        self.seq.load(SeqCst)
    }

    pub fn timing(&self) -> ArrivalTiming {
        ArrivalTiming {
            last_ns: self.last_ns.load(Acquire),
            interval_ns: self.interval_ns.load(Relaxed),
            spread_ns: self.spread_ns.load(Relaxed),
        }
    }

    /// Publishes a new arrival's timing; call before [`Doorbell::ring`] so a woken loop sees it.
    pub fn publish(&self, timing: ArrivalTiming) {
        self.interval_ns.store(timing.interval_ns, Relaxed);
        self.spread_ns.store(timing.spread_ns, Relaxed);
        self.last_ns.store(timing.last_ns, Release);
    }

    /// One sample is in the ring: count it and wake the loop if it waits for one.
    pub fn ring(&self) {
        // SeqCst on both sides (here: seq then armed; the waiter: armed then seq) means either
        // the waiter sees the new seq and does not sleep, or this side sees it armed and wakes it.
        self.seq.fetch_add(1, SeqCst);
        if self.armed.load(SeqCst) {
            futex_wake(&self.seq);
        }
    }

    /// Wakes the loop thread whatever it waits for (stop).
    pub fn wake(&self) {
        futex_wake(&self.seq);
    }

    /// Sleeps until `seq()` differs from `seq` or CLOCK_MONOTONIC reaches `deadline_ns`. May
    /// return early (a signal, a wake for stop): the caller re-checks both.
    pub fn wait(&self, seq: u32, deadline_ns: u64) {
        self.armed.store(true, SeqCst);
        if self.seq.load(SeqCst) == seq {
            futex_wait_until(&self.seq, seq, deadline_ns);
        }
        self.armed.store(false, SeqCst);
    }
}

fn futex_wait_until(word: &AtomicU32, expected: u32, deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: `word` is a live, aligned u32 for the duration of the call; FUTEX_WAIT_BITSET takes
    // an absolute CLOCK_MONOTONIC timeout (FUTEX_CLOCK_REALTIME is not set). Every outcome
    // (woken, timed out, EAGAIN because the word changed, EINTR) is handled by the caller's
    // re-check, so the return value is not needed.
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAIT_BITSET | libc::FUTEX_PRIVATE_FLAG,
            expected,
            &ts as *const libc::timespec,
            std::ptr::null::<u32>(),
            libc::FUTEX_BITSET_MATCH_ANY,
        );
    }
}

fn futex_wake(word: &AtomicU32) {
    // SAFETY: `word` is a live, aligned u32; FUTEX_WAKE only reads the address as a key.
    unsafe {
        libc::syscall(libc::SYS_futex, word.as_ptr(), libc::FUTEX_WAKE | libc::FUTEX_PRIVATE_FLAG, 1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::monotonic_ns;
    use std::sync::Arc;

    #[test]
    fn a_burst_is_one_arrival_and_the_period_is_learned() {
        let mut est = ArrivalEstimator::default();
        for k in 0..20u64 {
            let t = 1_000_000 + k * 1_000_000;
            assert!(est.observe(t).is_some(), "arrival {k}");
            // More frames of the same read (or a backlog), each within 50 µs of the last.
            for j in 1..=5 {
                assert_eq!(est.observe(t + j * 40_000), None);
            }
        }
        let timing = est.timing();
        assert_eq!(timing.last_ns, 20_000_000);
        assert_eq!(timing.interval_ns, 1_000_000);
        assert_eq!(timing.spread_ns, 0);
    }

    #[test]
    fn the_period_is_unknown_until_warmed_up_and_a_pause_does_not_throw_it() {
        let mut est = ArrivalEstimator::default();
        for k in 0..WARM_UP_INTERVALS as u64 {
            est.observe(k * 100_000);
            assert_eq!(est.timing().interval_ns, 0);
        }
        est.observe(8 * 100_000);
        assert_eq!(est.timing().interval_ns, 100_000);
        // A 1 s gap counts as at most 4 periods: the estimate moves by 1/8 of 3 periods.
        est.observe(1_000_000_000);
        assert_eq!(est.timing().interval_ns, 137_500);
    }

    #[test]
    fn a_ring_wakes_a_waiting_thread_before_its_deadline() {
        let bell = Arc::new(Doorbell::default());
        let seq = bell.seq();
        // A deadline far away (20 s): only the ring can end this wait before it.
        let far = monotonic_ns() + 20_000_000_000;
        let waiter = {
            let bell = bell.clone();
            std::thread::spawn(move || {
                while bell.seq() == seq && monotonic_ns() < far {
                    bell.wait(seq, far);
                }
                monotonic_ns() < far
            })
        };
        // Ring only once the waiter is armed, so the wake-up (not the re-check) must end it.
        while !bell.armed.load(SeqCst) {
            std::thread::yield_now();
        }
        bell.ring();
        assert!(waiter.join().unwrap(), "the ring did not wake the waiter");
        assert_eq!(bell.seq(), seq.wrapping_add(1));
    }

    #[test]
    fn a_wait_ends_at_its_deadline_without_a_ring() {
        let bell = Doorbell::default();
        let deadline = monotonic_ns() + 1_000_000;
        bell.wait(bell.seq(), deadline);
        while monotonic_ns() < deadline {
            bell.wait(bell.seq(), deadline); // an early (spurious) return is allowed
        }
        assert!(!bell.armed.load(SeqCst));
    }
}
