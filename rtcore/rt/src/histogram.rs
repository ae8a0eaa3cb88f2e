//! Fixed-bin, log-spaced timing histograms shared between the RT thread and Python.
//!
//! Why a histogram and not a sample buffer: percentiles of a run that lasts days need either
//! unbounded memory or sorting, both impossible in the loop. Fixed log-spaced bins (20 per
//! decade, 0.1 µs … 10 s) cost one `fetch_add` per record, never allocate, and give p50/p99/p999
//! within one bin (≈12 %). The exact maximum is kept beside them.
//!
//! Why atomics: the RT thread is the only writer; Python reads a snapshot at any time without a
//! lock the RT thread could ever wait on. Relaxed ordering suffices: a snapshot may miss the
//! record in flight, which statistics tolerate.
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

const BINS_PER_DECADE: usize = 20;
const DECADES: usize = 8;
/// Lower edge of the first log bin, in µs; anything below lands in bin 0.
const FLOOR_US: f64 = 0.1;
/// Bin 0 is the underflow bin, the last one the overflow bin.
pub const N_BINS: usize = BINS_PER_DECADE * DECADES + 2;

/// Percentiles of a histogram, in µs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Percentiles {
    pub count: u64,
    pub p50: f64,
    pub p99: f64,
    pub p999: f64,
    pub max: f64,
    pub mean: f64,
}

pub struct Histogram {
    bins: [AtomicU64; N_BINS],
    max_ns: AtomicU64,
    sum_ns: AtomicU64,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram {
            bins: std::array::from_fn(|_| AtomicU64::new(0)),
            max_ns: AtomicU64::new(0),
            sum_ns: AtomicU64::new(0),
        }
    }
}

fn bin_of(ns: u64) -> usize {
    let us = ns as f64 / 1_000.0;
    if us < FLOOR_US {
        return 0;
    }
    let k = ((us / FLOOR_US).log10() * BINS_PER_DECADE as f64).floor() as usize + 1;
    k.min(N_BINS - 1)
}

/// Upper edge of bin `k` in µs (the value a percentile falling in that bin reports).
fn upper_edge_us(k: usize) -> f64 {
    FLOOR_US * 10f64.powf(k as f64 / BINS_PER_DECADE as f64)
}

impl Histogram {
    /// Records one duration. Wait-free, no allocation.
    pub fn record(&self, ns: u64) {
        self.bins[bin_of(ns)].fetch_add(1, Relaxed);
        self.max_ns.fetch_max(ns, Relaxed);
        self.sum_ns.fetch_add(ns, Relaxed);
    }

    /// p50/p99/p999 (each the upper edge of its bin, never above the exact max), max and mean.
    pub fn percentiles(&self) -> Percentiles {
        let counts: [u64; N_BINS] = std::array::from_fn(|k| self.bins[k].load(Relaxed));
        let count: u64 = counts.iter().sum();
        if count == 0 {
            return Percentiles::default();
        }
        let max = self.max_ns.load(Relaxed) as f64 / 1_000.0;
        let quantile = |q: f64| {
            let rank = ((q * count as f64).ceil() as u64).max(1);
            let mut seen = 0;
            for (k, c) in counts.iter().enumerate() {
                seen += c;
                if seen >= rank {
                    return if k == N_BINS - 1 { max } else { upper_edge_us(k).min(max) };
                }
            }
            max
        };
        Percentiles {
            count,
            p50: quantile(0.5),
            p99: quantile(0.99),
            p999: quantile(0.999),
            max,
            mean: self.sum_ns.load(Relaxed) as f64 / 1_000.0 / count as f64,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_a_known_distribution_fall_in_their_bin() {
        let h = Histogram::default();
        // 1000 values: 1..=1000 µs.
        for us in 1..=1000u64 {
            h.record(us * 1_000);
        }
        let p = h.percentiles();
        assert_eq!(p.count, 1000);
        let within_a_bin = |got: f64, want: f64| got >= want && got <= want * 10f64.powf(0.05) + 1e-9;
        assert!(within_a_bin(p.p50, 500.0), "p50 {}", p.p50);
        assert!(within_a_bin(p.p99, 990.0), "p99 {}", p.p99);
        assert!(within_a_bin(p.p999, 999.0) || p.p999 == 1000.0, "p999 {}", p.p999);
        assert_eq!(p.max, 1000.0);
        assert!((p.mean - 500.5).abs() < 1e-9);
    }

    #[test]
    fn a_single_outlier_is_the_max_but_not_the_median() {
        let h = Histogram::default();
        for _ in 0..999 {
            h.record(50_000);
        }
        h.record(7_000_000);
        let p = h.percentiles();
        assert!(p.p50 < 60.0);
        assert!(p.p999 < 60.0);
        assert_eq!(p.max, 7_000.0);
    }

    #[test]
    fn empty_and_extreme_values() {
        let h = Histogram::default();
        assert_eq!(h.percentiles(), Percentiles::default());
        h.record(0);
        h.record(u64::MAX / 4);
        let p = h.percentiles();
        assert_eq!(p.count, 2);
        assert!(p.p50 <= FLOOR_US);
        assert_eq!(p.p999, p.max);
    }

    proptest::proptest! {
        #[test]
        fn percentiles_are_ordered_and_bounded_by_max(values in proptest::collection::vec(0u64..10_000_000_000, 1..300)) {
            let h = Histogram::default();
            for v in &values { h.record(*v); }
            let p = h.percentiles();
            proptest::prop_assert!(p.p50 <= p.p99 && p.p99 <= p.p999 && p.p999 <= p.max);
            proptest::prop_assert_eq!(p.max, *values.iter().max().unwrap() as f64 / 1000.0);
        }
    }
}
