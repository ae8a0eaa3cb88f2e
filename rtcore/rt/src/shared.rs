//! What the loop thread and its handle share: statistics, command flags, the measured bias, the
//! warnings, and the fault state (the bus link, each servo's recovery, the stop request).
//!
//! Commands are atomics the loop polls once per cycle (stop, tare), never channels it could
//! block on. The warnings list is a `Mutex<Vec>` because only setup and shutdown (outside the
//! cycle) write to it.
use crate::fault::ExternalFaults;
use crate::params::Limits;
use crate::passivity::PassivityShared;
use crate::recovery::{Phase, ServoCounts, ServoView, StopRequest};
use crate::telemetry::LoopStats;
use crate::trigger::TriggerStats;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};

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
    /// The bus's port: lost, reopened (written by the loop and the port's reopen helper).
    pub link: Arc<LinkStats>,
    /// Each joint's servo as its recovery sees it (`Shared::for_joints`; empty otherwise).
    pub servos: Box<[ServoShared]>,
    /// The loop's stop request (`StopRequest::encode`; 0 = none).
    pub stop_request: AtomicU64,
    /// Faults raised from outside (the sensor's), marked in the records.
    pub external_faults: ExternalFaults,
    /// Each joint's limits as the loop adopted them (`Limits` fields as f64 bits): what
    /// `params()` reports, so a get shows what the loop enforces, not only what was accepted.
    adopted_limits: Box<[[AtomicU64; 4]]>,
    /// Each joint's passivity guard (`Shared::for_joints`; empty otherwise).
    pub passivity: Box<[PassivityShared]>,
}

/// The bus's port as the loop and its reopen helper see it.
#[derive(Default)]
pub struct LinkStats {
    /// CLOCK_MONOTONIC when it was lost; 0 while it is up.
    pub lost_since_ns: AtomicU64,
    pub losses: AtomicU64,
    /// The errno of the failure that lost it (0: none known, e.g. a hang-up).
    pub loss_errno: AtomicI32,
    pub reconnects: AtomicU64,
    /// Reopen attempts of the helper, and those that failed.
    pub reopen_attempts: AtomicU64,
    pub reopen_failures: AtomicU64,
    /// Why the port was lost, then why the last reopen failed (never written by the loop thread).
    pub last_error: Mutex<String>,
    /// The transport the loop started on (`Transport::kind`).
    pub kind: Mutex<&'static str>,
    /// The present-position read the loop uses (`JointBus::read_name`; empty before a start).
    pub read: Mutex<&'static str>,
}

impl LinkStats {
    pub fn note_error(&self, text: String) {
        if let Ok(mut e) = self.last_error.lock() {
            *e = text;
        }
    }

    pub fn last_error(&self) -> String {
        self.last_error.lock().map(|e| e.clone()).unwrap_or_default()
    }
}

/// One servo's recovery, published by the loop each cycle (a few relaxed stores).
#[derive(Default)]
pub struct ServoShared {
    phase: AtomicU8,
    hardware_error: AtomicU8,
    last_error: AtomicU8,
    silent: AtomicBool,
    counts: [AtomicU64; 7],
}

/// One servo's recovery as the supervisor reads it (`ServoView` with the phase's name).
#[derive(Debug, Clone, Copy)]
pub struct ServoSnapshot {
    pub phase: &'static str,
    pub hardware_error: u8,
    pub last_error: u8,
    pub silent: bool,
    pub counts: ServoCounts,
}

impl ServoShared {
    pub fn publish(&self, v: &ServoView) {
        self.phase.store(v.phase.code(), Ordering::Relaxed);
        self.hardware_error.store(v.hardware_error, Ordering::Relaxed);
        self.last_error.store(v.last_error, Ordering::Relaxed);
        self.silent.store(v.silent, Ordering::Relaxed);
        let c = &v.counts;
        for (slot, n) in self.counts.iter().zip([c.errors, c.tolerated, c.torque_offs, c.reboots, c.reenables, c.recoveries, c.silences]) {
            slot.store(n, Ordering::Relaxed);
        }
    }

    pub fn snapshot(&self) -> ServoSnapshot {
        let n = |k: usize| self.counts[k].load(Ordering::Relaxed);
        let phase = Phase::NAMES.get(usize::from(self.phase.load(Ordering::Relaxed))).copied().unwrap_or("ok");
        let counts = ServoCounts { errors: n(0), tolerated: n(1), torque_offs: n(2), reboots: n(3), reenables: n(4), recoveries: n(5), silences: n(6) };
        ServoSnapshot {
            phase,
            hardware_error: self.hardware_error.load(Ordering::Relaxed),
            last_error: self.last_error.load(Ordering::Relaxed),
            silent: self.silent.load(Ordering::Relaxed),
            counts,
        }
    }
}

impl Shared {
    /// Shared state with room for `joints` servos' recovery.
    pub fn for_joints(joints: usize) -> Shared {
        Shared {
            servos: (0..joints).map(|_| ServoShared::default()).collect(),
            adopted_limits: (0..joints).map(|_| Default::default()).collect(),
            passivity: (0..joints).map(|_| PassivityShared::default()).collect(),
            ..Default::default()
        }
    }

    /// The loop adopted `limits` for joint `k` (a few relaxed stores; any thread reads them).
    pub fn publish_limits(&self, k: usize, limits: &Limits) {
        if let Some(slots) = self.adopted_limits.get(k) {
            let values = [limits.position_min, limits.position_max, limits.velocity_max, limits.acceleration_max];
            for (slot, v) in slots.iter().zip(values) {
                slot.store(v.to_bits(), Ordering::Relaxed);
            }
        }
    }

    /// Joint `k`'s limits as the loop adopted them, if it has published any.
    pub fn adopted_limits(&self, k: usize) -> Option<Limits> {
        let v = self.adopted_limits.get(k)?.each_ref().map(|slot| f64::from_bits(slot.load(Ordering::Relaxed)));
        Some(Limits { position_min: v[0], position_max: v[1], velocity_max: v[2], acceleration_max: v[3] })
    }

    pub fn stop_request(&self) -> Option<StopRequest> {
        StopRequest::decode(self.stop_request.load(Ordering::Relaxed))
    }

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
