//! The loop's fault model: what can go wrong inside a cycle, how it is marked, counted and shown.
//!
//! Three pieces, each one place to extend:
//!
//! - [`FaultKind`]: one variant per thing that can go wrong, each with one bit (in the
//!   telemetry `Record::fault`, so in the state message and the recording's rows) and one
//!   name (its counter in `stats()["faults"]`). A new kind is a new variant, appended to
//!   [`FaultKind::ALL`] with the next free bit; nothing else changes shape.
//! - [`Faults`]: the set of kinds active in one cycle (a bitmask, `Copy`, no allocation).
//! - [`FaultCounters`]: per-kind counts of *events* (a kind becoming active after a cycle
//!   without it), as atomics the RT thread bumps and any thread reads.
//!
//! And [`LoopMode`]: what the loop as a whole is doing (running, holding by policy, or
//! faulted), stored each cycle for `stats()["mode"]` and written into every record.
//!
//! The policy of every kind starts with *hold*: the joint keeps its last good state, velocity
//! zero, so its goal stays where it was. A fault is judged anew each cycle: when its cause is
//! gone (a state that was restored, a new parameter set, a servo recovered, the bus back), the
//! joint runs again and the mode goes back to running; the counter keeps the event. What else
//! is done about a servo or bus fault (read the error, reboot, re-enable, reopen, or stop) is
//! the recovery's business (`recovery`, `link`); the sensor kinds are raised from outside the
//! loop by the supervisor, which watches the sensor's reader (`ExternalFaults`).
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering::Relaxed};

/// One thing that can go wrong inside a cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum FaultKind {
    /// A joint's model state (θ, ω) was not finite or outside what any accepted set allows, or
    /// its ramped gains were not usable: the joint holds at its last good state.
    ModelStateInvalid = 0,
    /// A servo's status packets carry the hardware alert, or its Hardware Error Status is not 0
    /// (a shutdown: overload, voltage, overheating, encoder, electrical shock).
    ServoError = 1,
    /// A servo's Torque Enable reads 0 while the loop drives it, with no hardware error (torque
    /// found off: a brown-out's reset, another client's write).
    TorqueOff = 2,
    /// A servo has not answered for `servo_silent_ms` (a brown-out, a cable, a reboot gone wrong).
    ServoSilent = 3,
    /// The bus's port failed (EIO, hang-up: the adapter unplugged); being reopened.
    BusLost = 4,
    /// The force sensor's device failed and its reader is reopening it (raised by the supervisor).
    SensorLost = 5,
    /// The force sensor reported saturated samples (raised by the supervisor).
    SensorSaturated = 6,
    /// A servo's position read jumped farther than any horn can turn since the last trusted
    /// read (`anchor`), or an anchoring read was not confirmed: the read is kept out of the
    /// model, the goal and the record's present position. A mark, not a hold: the joint runs on.
    PositionGlitch = 7,
}

impl FaultKind {
    /// Every kind, in bit order.
    pub const ALL: [FaultKind; 8] = [
        FaultKind::ModelStateInvalid,
        FaultKind::ServoError,
        FaultKind::TorqueOff,
        FaultKind::ServoSilent,
        FaultKind::BusLost,
        FaultKind::SensorLost,
        FaultKind::SensorSaturated,
        FaultKind::PositionGlitch,
    ];

    /// The kinds raised from outside the loop (`ExternalFaults`): the sensor's.
    pub const EXTERNAL: Faults = Faults(FaultKind::SensorLost.bit() | FaultKind::SensorSaturated.bit());

    /// The kinds that mark a record without holding a joint: the loop's mode stays running.
    pub const MARKS: Faults = Faults(FaultKind::PositionGlitch.bit());

    pub const fn bit(self) -> u64 {
        1 << (self as u8)
    }

    /// Its name in `stats()["faults"]` and in the documentation.
    pub const fn name(self) -> &'static str {
        match self {
            FaultKind::ModelStateInvalid => "model_state_invalid",
            FaultKind::ServoError => "servo_error",
            FaultKind::TorqueOff => "torque_off",
            FaultKind::ServoSilent => "servo_silent",
            FaultKind::BusLost => "bus_lost",
            FaultKind::SensorLost => "sensor_lost",
            FaultKind::SensorSaturated => "sensor_saturated",
            FaultKind::PositionGlitch => "position_glitch",
        }
    }
}

/// A set of fault kinds (the bits of [`FaultKind::bit`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Faults(u64);

impl Faults {
    pub const NONE: Faults = Faults(0);

    pub fn insert(&mut self, kind: FaultKind) {
        self.0 |= kind.bit();
    }

    pub fn contains(self, kind: FaultKind) -> bool {
        self.0 & kind.bit() != 0
    }

    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    pub fn bits(self) -> u64 {
        self.0
    }

    pub fn union(self, other: Faults) -> Faults {
        Faults(self.0 | other.0)
    }

    pub fn intersection(self, other: Faults) -> Faults {
        Faults(self.0 & other.0)
    }

    pub const fn from_bits(bits: u64) -> Faults {
        Faults(bits)
    }
}

impl From<FaultKind> for Faults {
    fn from(kind: FaultKind) -> Faults {
        Faults(kind.bit())
    }
}

/// Faults raised from outside the loop (the supervisor, which watches the sensor's reader): one
/// atomic the loop reads each cycle, so the records mark those cycles like any other fault.
#[derive(Default)]
pub struct ExternalFaults(AtomicU64);

impl ExternalFaults {
    /// Sets the external kinds active now; other kinds are ignored.
    pub fn set(&self, faults: Faults) {
        self.0.store(faults.intersection(FaultKind::EXTERNAL).bits(), Relaxed);
    }

    pub fn get(&self) -> Faults {
        Faults(self.0.load(Relaxed))
    }
}

/// What the loop as a whole does this cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum LoopMode {
    /// Every joint follows its model.
    Running = 0,
    /// The joints hold by policy (the force is stale), with no fault.
    Holding = 1,
    /// A fault is active: the joints it concerns hold at their last good state.
    Faulted = 2,
}

impl LoopMode {
    /// Every mode, in code order.
    pub const ALL: [LoopMode; 3] = [LoopMode::Running, LoopMode::Holding, LoopMode::Faulted];

    pub const fn name(self) -> &'static str {
        match self {
            LoopMode::Running => "running",
            LoopMode::Holding => "holding",
            LoopMode::Faulted => "faulted",
        }
    }

    pub fn from_code(code: u8) -> LoopMode {
        match code {
            1 => LoopMode::Holding,
            2 => LoopMode::Faulted,
            _ => LoopMode::Running,
        }
    }

    /// Faulted beats holding beats running.
    pub fn of(faults: Faults, holding: bool) -> LoopMode {
        if !Faults(faults.0 & !FaultKind::MARKS.0).is_empty() {
            LoopMode::Faulted
        } else if holding {
            LoopMode::Holding
        } else {
            LoopMode::Running
        }
    }
}

/// Per-kind event counters and the current mode, shared by the loop thread and its readers.
pub struct FaultCounters {
    events: [AtomicU64; FaultKind::ALL.len()],
    mode: AtomicU8,
    /// The kinds active in the previous cycle (rising edges are events). Only the loop thread
    /// writes it; an atomic only so the struct can be shared.
    previous: AtomicU64,
}

impl Default for FaultCounters {
    fn default() -> Self {
        FaultCounters {
            events: std::array::from_fn(|_| AtomicU64::new(0)),
            mode: AtomicU8::new(LoopMode::Running as u8),
            previous: AtomicU64::new(0),
        }
    }
}

impl FaultCounters {
    /// Records one cycle's faults and mode: counts each kind that became active.
    pub fn record(&self, active: Faults, mode: LoopMode) {
        let previous = Faults(self.previous.swap(active.bits(), Relaxed));
        for (kind, counter) in FaultKind::ALL.iter().zip(&self.events) {
            if active.contains(*kind) && !previous.contains(*kind) {
                counter.fetch_add(1, Relaxed);
            }
        }
        self.mode.store(mode as u8, Relaxed);
    }

    pub fn events(&self, kind: FaultKind) -> u64 {
        self.events[kind as usize].load(Relaxed)
    }

    pub fn mode(&self) -> LoopMode {
        LoopMode::from_code(self.mode.load(Relaxed))
    }

    /// (name, events) of every kind, in bit order.
    pub fn snapshot(&self) -> Vec<(&'static str, u64)> {
        FaultKind::ALL.iter().map(|k| (k.name(), self.events(*k))).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_are_distinct_and_in_order() {
        for (k, kind) in FaultKind::ALL.iter().enumerate() {
            assert_eq!(kind.bit(), 1 << k);
            assert_eq!(*kind as usize, k);
        }
    }

    #[test]
    fn mode_codes_round_trip() {
        for (code, mode) in LoopMode::ALL.iter().enumerate() {
            assert_eq!(LoopMode::from_code(code as u8), *mode);
        }
    }

    #[test]
    fn events_are_rising_edges_and_the_mode_follows() {
        let c = FaultCounters::default();
        let mut bad = Faults::NONE;
        bad.insert(FaultKind::ModelStateInvalid);
        c.record(Faults::NONE, LoopMode::of(Faults::NONE, true));
        assert_eq!(c.mode(), LoopMode::Holding);
        for _ in 0..3 {
            c.record(bad, LoopMode::of(bad, false));
        }
        assert_eq!(c.events(FaultKind::ModelStateInvalid), 1, "one event, however long it lasts");
        assert_eq!(c.mode(), LoopMode::Faulted);
        c.record(Faults::NONE, LoopMode::of(Faults::NONE, false));
        c.record(bad, LoopMode::Faulted);
        assert_eq!(c.snapshot()[0], ("model_state_invalid", 2));
        assert!(c.snapshot()[1..].iter().all(|(_, n)| *n == 0));
    }

    #[test]
    fn only_the_sensor_kinds_come_from_outside() {
        let outside = ExternalFaults::default();
        outside.set(Faults::from_bits(u64::MAX));
        assert_eq!(outside.get(), FaultKind::EXTERNAL);
        assert!(outside.get().contains(FaultKind::SensorLost) && !outside.get().contains(FaultKind::BusLost));
    }
}
