//! What the loop thread and its handle share: statistics, command flags, the measured bias and
//! the warnings.
//!
//! Commands are atomics the loop polls once per cycle (stop, tare), never channels it could
//! block on. The warnings list is a `Mutex<Vec>` because only setup and shutdown (outside the
//! cycle) write to it.
use crate::telemetry::LoopStats;
use crate::trigger::TriggerStats;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;

#[derive(Default)]
pub struct Shared {
    pub stats: LoopStats,
    /// How the cycles started (runner only).
    pub trigger: TriggerStats,
    pub stop: AtomicBool,
    pub running: AtomicBool,
    /// Samples to average for a tare; the loop takes it (swaps in 0) when it starts the tare.
    pub tare_request: AtomicU32,
    bias: [AtomicU64; 6],
    warnings: Mutex<Vec<String>>,
}

impl Shared {
    /// The bias the loop subtracts now (as last published by the loop).
    pub fn bias(&self) -> [f64; 6] {
        std::array::from_fn(|k| f64::from_bits(self.bias[k].load(Ordering::Relaxed)))
    }

    pub fn publish_bias(&self, bias: &[f64; 6]) {
        for (slot, b) in self.bias.iter().zip(bias) {
            slot.store(b.to_bits(), Ordering::Relaxed);
        }
    }

    pub fn warn(&self, message: String) {
        if let Ok(mut w) = self.warnings.lock() {
            w.push(message);
        }
    }

    pub fn warnings(&self) -> Vec<String> {
        self.warnings.lock().map(|w| w.clone()).unwrap_or_default()
    }
}
