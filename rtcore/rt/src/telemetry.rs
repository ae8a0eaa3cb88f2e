//! The per-cycle telemetry record and the counters and histograms the loop shares with Python.
//!
//! Why one record per joint per cycle: a fixed-size record with a joint id works for any number
//! of joints without a maximum compiled in, and maps one-to-one onto a numpy structured array
//! (every field 8 bytes wide: no padding, so the byte layout is simply the fields in order).
//!
//! Why counters are atomics: the RT thread writes them with uncontended relaxed operations and
//! Python reads them whenever it likes; there is no lock the loop could wait on.
use crate::bus::BusErrorKind;
use crate::fault::{FaultCounters, LoopMode};
use crate::histogram::{Histogram, Percentiles};
use crate::sched::RtReport;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Mutex;

/// One joint's view of one cycle.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Record {
    pub cycle: u64,
    /// CLOCK_MONOTONIC at the cycle's start (its wake-up).
    pub t_ns: u64,
    /// The cycle's deadline on the model's clock (CLOCK_MONOTONIC): the time the model's state
    /// has been integrated up to, in whole steps of one period; the grid point this cycle stands
    /// for, within half a period of the (phase-locked) grid. Recordings stamp rows with it. A
    /// cycle that took no step (a grid that moved back) repeats the previous one's.
    pub deadline_ns: u64,
    pub id: i64,
    /// The conditioned force on the joint's axis (after tare, deadband, low-pass).
    pub force: f64,
    /// The user torque applied to the model, N·m.
    pub torque: f64,
    pub theta: f64,
    pub omega: f64,
    pub goal_tick: i64,
    /// The tick read this cycle, or −1 when none was read.
    pub present_tick: i64,
    /// How late the cycle woke after the moment it was due: its grid point on the schedule; with
    /// the sample trigger the window's opening, the push of the sample that started it, or the
    /// window's end. Not a time base: a cycle may start before `deadline_ns` + this.
    pub period_error_ns: i64,
    /// Arrival of the sample this SyncWrite used first → end of the write; −1 when no new sample.
    pub latency_ns: i64,
    /// The faults active for this joint this cycle (its own and the loop's): `FaultKind::bit`s.
    pub fault: u64,
    /// The loop's mode this cycle: `LoopMode` as a number (0 running, 1 holding, 2 faulted).
    pub mode: i64,
    /// J: the passivity guard's windowed energy balance (`passivity`; < −margin: the joint
    /// generated energy and the guard acts).
    pub passivity_energy: f64,
    /// N·m·s/rad: the damping the passivity guard adds to the model this cycle (0: none).
    pub passivity_damping: f64,
}

/// The field names in layout order, each 8 bytes: (name, numpy type code).
pub const RECORD_FIELDS: [(&str, &str); 16] = [
    ("cycle", "<u8"),
    ("t_ns", "<u8"),
    ("deadline_ns", "<u8"),
    ("id", "<i8"),
    ("force", "<f8"),
    ("torque", "<f8"),
    ("theta", "<f8"),
    ("omega", "<f8"),
    ("goal_tick", "<i8"),
    ("present_tick", "<i8"),
    ("period_error_ns", "<i8"),
    ("latency_ns", "<i8"),
    ("fault", "<u8"),
    ("mode", "<i8"),
    ("passivity_energy", "<f8"),
    ("passivity_damping", "<f8"),
];

impl Record {
    /// Appends the record's fields, little-endian, in `RECORD_FIELDS` order.
    pub fn write_le(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.cycle.to_le_bytes());
        out.extend_from_slice(&self.t_ns.to_le_bytes());
        out.extend_from_slice(&self.deadline_ns.to_le_bytes());
        out.extend_from_slice(&self.id.to_le_bytes());
        for v in [self.force, self.torque, self.theta, self.omega] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in [self.goal_tick, self.present_tick, self.period_error_ns, self.latency_ns] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&self.fault.to_le_bytes());
        out.extend_from_slice(&self.mode.to_le_bytes());
        out.extend_from_slice(&self.passivity_energy.to_le_bytes());
        out.extend_from_slice(&self.passivity_damping.to_le_bytes());
    }
}

/// Counters and histograms written by the loop, read by anyone.
#[derive(Default)]
pub struct LoopStats {
    pub cycles: AtomicU64,
    pub overruns: AtomicU64,
    pub bus_errors: AtomicU64,
    /// `bus_errors` split by where they came from, in `BusErrorKind::ALL` order.
    bus_error_kinds: [AtomicU64; BusErrorKind::ALL.len()],
    pub sensor_samples: AtomicU64,
    pub sensor_stale_events: AtomicU64,
    pub telemetry_drops: AtomicU64,
    pub sync_reads: AtomicU64,
    /// SyncReads of the present positions deferred a cycle to give a waiting servo recovery the
    /// bus (`cycle`, `RECOVERY_WAIT_CYCLES`): non-zero says the bus is too busy for its cycle.
    pub reads_deferred: AtomicU64,
    /// Times a joint's servo compensation made its horn worse than none and was turned off.
    pub compensation_fallbacks: AtomicU64,
    pub period: Histogram,
    pub latency: Histogram,
    /// Wake-up → end of the cycle's bus traffic: what a cycle costs.
    pub work: Histogram,
    /// Fault events per kind, and the loop's mode (see `fault`).
    pub faults: FaultCounters,
    /// Set once by the loop thread before its first cycle.
    pub rt: Mutex<RtReport>,
}

/// A copy of the statistics at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct StatsSnapshot {
    pub cycles: u64,
    pub overruns: u64,
    pub rate_hz: f64,
    pub period_us: Percentiles,
    pub latency_us: Percentiles,
    pub work_us: Percentiles,
    pub bus_errors: u64,
    /// (kind name, errors), every kind.
    pub bus_error_kinds: Vec<(&'static str, u64)>,
    pub sensor_samples: u64,
    pub sensor_stale_events: u64,
    pub telemetry_drops: u64,
    pub sync_reads: u64,
    pub reads_deferred: u64,
    pub compensation_fallbacks: u64,
    /// (kind name, events), every kind.
    pub faults: Vec<(&'static str, u64)>,
    pub mode: LoopMode,
    pub rt: RtReport,
}

impl LoopStats {
    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Relaxed);
    }

    /// Counts one bus error, in the total and under its kind.
    pub fn bus_error(&self, kind: BusErrorKind) {
        self.bus_errors.fetch_add(1, Relaxed);
        self.bus_error_kinds[kind as usize].fetch_add(1, Relaxed);
    }

    pub fn snapshot(&self, rate_hz: f64) -> StatsSnapshot {
        StatsSnapshot {
            cycles: self.cycles.load(Relaxed),
            overruns: self.overruns.load(Relaxed),
            rate_hz,
            period_us: self.period.percentiles(),
            latency_us: self.latency.percentiles(),
            work_us: self.work.percentiles(),
            bus_errors: self.bus_errors.load(Relaxed),
            bus_error_kinds: BusErrorKind::ALL.iter().map(|k| (k.name(), self.bus_error_kinds[*k as usize].load(Relaxed))).collect(),
            sensor_samples: self.sensor_samples.load(Relaxed),
            sensor_stale_events: self.sensor_stale_events.load(Relaxed),
            telemetry_drops: self.telemetry_drops.load(Relaxed),
            sync_reads: self.sync_reads.load(Relaxed),
            reads_deferred: self.reads_deferred.load(Relaxed),
            compensation_fallbacks: self.compensation_fallbacks.load(Relaxed),
            faults: self.faults.snapshot(),
            mode: self.faults.mode(),
            rt: self.rt.lock().map(|r| r.clone()).unwrap_or_default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_byte_layout_matches_the_field_table() {
        let r = Record {
            cycle: 1,
            deadline_ns: 7,
            id: -2,
            theta: 0.5,
            latency_ns: -1,
            fault: 1,
            mode: 2,
            passivity_damping: 0.25,
            ..Default::default()
        };
        let mut out = Vec::new();
        r.write_le(&mut out);
        assert_eq!(out.len(), 8 * RECORD_FIELDS.len());
        let field = |name: &str| {
            let k = RECORD_FIELDS.iter().position(|(n, _)| *n == name).unwrap();
            <[u8; 8]>::try_from(&out[8 * k..8 * k + 8]).unwrap()
        };
        assert_eq!(u64::from_le_bytes(field("cycle")), 1);
        assert_eq!(u64::from_le_bytes(field("deadline_ns")), 7);
        assert_eq!(i64::from_le_bytes(field("id")), -2);
        assert_eq!(f64::from_le_bytes(field("theta")), 0.5);
        assert_eq!(i64::from_le_bytes(field("latency_ns")), -1);
        assert_eq!(u64::from_le_bytes(field("fault")), 1);
        assert_eq!(i64::from_le_bytes(field("mode")), 2);
        assert_eq!(f64::from_le_bytes(field("passivity_damping")), 0.25);
    }
}
