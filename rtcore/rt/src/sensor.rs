//! Force samples from Python to the loop: the lock-free ring, newest-sample selection and
//! staleness.
//!
//! Why a ring drained to the newest sample rather than a single "latest" slot: the ring keeps
//! every sample's own arrival time (for the latency histogram), lets a tare request average
//! all samples rather than one per cycle, and lets the loop count what arrived. Only the newest
//! drives the model: older ones in the same cycle are already superseded.
//!
//! Why stale means hold: integrating an old force keeps pushing the joint with a hand that may
//! have let go long ago. A sample older than `stale_timeout` (or none at all since the loop
//! started) holds the joint still: the loop zeroes the velocity and stops integrating until a
//! fresh sample arrives, and counts one event each time it goes stale.
use crate::filter::TareAverager;

/// A force sample: `t_ns` = CLOCK_MONOTONIC at arrival; `forces` = [fx, fy, fz, tx, ty, tz].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ForceSample {
    pub t_ns: u64,
    pub forces: [f64; 6],
}

/// What `take` found this cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intake {
    /// The newest sample so far (zeros before the first one).
    pub newest: ForceSample,
    /// A sample arrived this cycle that no SyncWrite has used yet.
    pub new_arrival: bool,
    /// How many samples were drained this cycle.
    pub drained: u64,
    /// The newest sample is older than the stale timeout.
    pub stale: bool,
    /// This cycle is the one where the data went stale.
    pub became_stale: bool,
}

pub struct ForceIntake {
    ring: rtrb::Consumer<ForceSample>,
    newest: ForceSample,
    /// Time of the newest sample, or the loop's start before the first one.
    fresh_since_ns: u64,
    stale: bool,
}

impl ForceIntake {
    pub fn new(ring: rtrb::Consumer<ForceSample>) -> Self {
        ForceIntake { ring, newest: ForceSample::default(), fresh_since_ns: 0, stale: false }
    }

    /// Starts the stale clock: without a sample by `now_ns + timeout`, the data counts as stale.
    pub fn start(&mut self, now_ns: u64) {
        self.fresh_since_ns = now_ns;
        self.stale = false;
    }

    /// Drains the ring to its newest sample, feeding every raw sample to a tare in progress, and
    /// judges staleness at `now_ns`. Returns the cycle's intake and the bias of a finished tare.
    pub fn take(&mut self, now_ns: u64, stale_timeout_ns: u64, tare: &mut TareAverager) -> (Intake, Option<[f64; 6]>) {
        let mut drained = 0;
        let mut tared = None;
        while let Ok(sample) = self.ring.pop() {
            drained += 1;
            self.newest = sample;
            tared = tare.add(&sample.forces).or(tared);
        }
        if drained > 0 {
            self.fresh_since_ns = self.newest.t_ns;
        }
        let stale = now_ns.saturating_sub(self.fresh_since_ns) > stale_timeout_ns;
        let became_stale = stale && !self.stale;
        self.stale = stale;
        let intake = Intake { newest: self.newest, new_arrival: drained > 0, drained, stale, became_stale };
        (intake, tared)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn intake(capacity: usize) -> (rtrb::Producer<ForceSample>, ForceIntake) {
        let (tx, rx) = rtrb::RingBuffer::new(capacity);
        (tx, ForceIntake::new(rx))
    }

    fn sample(t_ns: u64, fx: f64) -> ForceSample {
        ForceSample { t_ns, forces: [fx, 0.0, 0.0, 0.0, 0.0, 0.0] }
    }

    #[test]
    fn the_newest_sample_wins_and_every_sample_is_counted() {
        let (mut tx, mut rx) = intake(8);
        rx.start(0);
        for k in 1..=3 {
            tx.push(sample(k * 10, k as f64)).unwrap();
        }
        let (got, _) = rx.take(40, 1_000, &mut TareAverager::default());
        assert_eq!(got.newest, sample(30, 3.0));
        assert_eq!((got.drained, got.new_arrival, got.stale), (3, true, false));
        let (again, _) = rx.take(50, 1_000, &mut TareAverager::default());
        assert_eq!((again.drained, again.new_arrival), (0, false));
        assert_eq!(again.newest, sample(30, 3.0));
    }

    #[test]
    fn staleness_counts_once_per_episode_and_clears_on_a_fresh_sample() {
        let (mut tx, mut rx) = intake(8);
        rx.start(1_000);
        let mut tare = TareAverager::default();
        assert!(!rx.take(1_500, 1_000, &mut tare).0.stale);
        // No sample at all since the start: stale after the timeout, counted once.
        let first = rx.take(2_001, 1_000, &mut tare).0;
        assert!(first.stale && first.became_stale);
        let second = rx.take(2_500, 1_000, &mut tare).0;
        assert!(second.stale && !second.became_stale);
        tx.push(sample(2_600, 1.0)).unwrap();
        assert!(!rx.take(2_700, 1_000, &mut tare).0.stale);
        // An old sample is stale at once.
        tx.push(sample(100, 1.0)).unwrap();
        assert!(rx.take(2_800, 1_000, &mut tare).0.became_stale);
    }

    #[test]
    fn a_tare_sees_every_sample_not_only_the_newest() {
        let (mut tx, mut rx) = intake(8);
        let mut tare = TareAverager::default();
        tare.request(4);
        for k in 0..4 {
            tx.push(sample(k, k as f64)).unwrap();
        }
        let (_, bias) = rx.take(10, 1_000, &mut tare);
        assert_eq!(bias.unwrap()[0], 1.5);
    }
}
