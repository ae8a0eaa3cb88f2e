//! The servos' recovery on a busy bus: a SyncRead of the present positions that takes most of
//! the cycle must not starve the recovery's transactions (each needs a quarter cycle left for
//! its reply), and the recovery must not starve the SyncRead either.
//!
//! The bus here has time: a clock shared with the transport, which advances it by what each
//! packet costs and by when each reply arrives (a reply later than its deadline is lost, as on
//! a serial port: the read times out), so a cycle sees its time run out as on a slow bus.
use super::tests::{rig, Rig, PERIOD};
use super::*;
use crate::bus::memory::MemoryTransport;
use crate::clock::SharedClock;
use crate::recovery::{FaultPolicy, Phase};
use crate::sensor::ForceSample;

/// One request on the wire: its instruction, when it was sent and the deadline of its reply.
#[derive(Debug, Clone, Copy)]
struct Sent {
    instruction: u8,
    at_ns: u64,
    deadline_ns: Option<u64>,
}

/// The in-memory servos behind a bus with time: every packet costs `packet_ns` to send (the
/// SyncWrite of the goals `sync_write_ns`), a SyncRead's replies arrive `sync_read_ns` after it,
/// any other reply `packet_ns` after its request; a servo that does not answer costs the wait
/// to the deadline.
struct BusyBus {
    wire: MemoryTransport,
    clock: SharedClock,
    packet_ns: u64,
    sync_write_ns: u64,
    sync_read_ns: u64,
    /// When the replies of the request in flight arrive (None: none expected, or read).
    reply_at: Option<u64>,
    sent: Vec<Sent>,
}

const SYNC_WRITE: u8 = 0x83;
const SYNC_READS: [u8; 2] = [0x82, 0x8A];

impl Transport for BusyBus {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let at_ns = self.clock.now_ns();
        let instruction = bytes[7];
        self.clock.advance_to(at_ns + if instruction == SYNC_WRITE { self.sync_write_ns } else { self.packet_ns });
        let latency = if SYNC_READS.contains(&instruction) { self.sync_read_ns } else { self.packet_ns };
        self.reply_at = (instruction != SYNC_WRITE).then_some(self.clock.now_ns() + latency);
        self.sent.push(Sent { instruction, at_ns, deadline_ns: None });
        self.wire.write_all(bytes)
    }

    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> std::io::Result<usize> {
        if let Some(last) = self.sent.last_mut() {
            last.deadline_ns.get_or_insert(deadline_ns);
        }
        if let Some(at) = self.reply_at.take() {
            if at > deadline_ns {
                self.clock.sleep_until(deadline_ns);
                self.wire.wire().replies.clear(); // too late: the read timed out
                return Ok(0);
            }
            self.clock.sleep_until(at);
        }
        let n = self.wire.read_until(buf, deadline_ns)?;
        if n == 0 {
            self.clock.sleep_until(deadline_ns); // nothing comes: the wait lasts to the deadline
        }
        Ok(n)
    }
}

/// A loop that drives `ids` (torque on at start) at 1 kHz, reading them every cycle, over a bus
/// whose SyncRead replies come `sync_read_ns` after the request.
fn busy(ids: &[u8], sync_read_ns: u64, packet_ns: u64) -> (Rig, BusyBus) {
    let present: Vec<(u8, i64)> = ids.iter().map(|&id| (id, 2048)).collect();
    let mut p = crate::params::tests::params(ids.len());
    for j in &mut p.joints {
        *j = super::tests::free_joint().joints[0];
    }
    let mut r = rig(p, &present);
    r.ctl.set_fault_policy(FaultPolicy::default(), true);
    r.ctl.sync_read_divisor = 1;
    let clock = SharedClock::default();
    clock.advance_to(1_000_000_000);
    let mut bus = BusyBus { wire: r.bus.clone(), clock, packet_ns, sync_write_ns: packet_ns, sync_read_ns, reply_at: None, sent: Vec::new() };
    let start_deadline = bus.clock.now_ns() + 100 * PERIOD;
    let clock = bus.clock.clone();
    r.ctl.start_at_present(&mut bus, &clock, start_deadline, true).unwrap();
    r.ctl.begin(clock.now_ns());
    bus.sent.clear();
    (r, bus)
}

/// Runs one cycle on the next grid point (a still hand), its records drained.
fn cycle(r: &mut Rig, bus: &mut BusyBus) {
    let mut clock = bus.clock.clone();
    let due = (clock.now_ns() / PERIOD + 1) * PERIOD;
    clock.sleep_until(due);
    r.force.push(ForceSample { t_ns: clock.now_ns(), forces: [0.0; 6] }).unwrap();
    r.ctl.run_cycle(bus, &clock, due, due);
    while r.telemetry.pop().is_ok() {}
}

fn recovered(r: &Rig, bus: &BusyBus, k: usize) -> bool {
    let view = r.ctl.recovery.view(k).unwrap();
    view.phase == Phase::Ok && view.counts.recoveries >= 1 && bus.wire.wire().torque_of(k as u8 + 1)
}

/// After torque goes off on joint 1 (a brown-out's reset, no error): the cycles until the
/// round-robin's check found it (the joint's recovery began), and then until it recovered
/// (diagnosed, re-anchored, torque on, verified); None for what did not happen within `max`.
fn cycles_to_recover(r: &mut Rig, bus: &mut BusyBus, max: usize) -> (Option<usize>, Option<usize>) {
    bus.wire.wire().set_torque(1, false);
    let found = (1..=max).find(|_| {
        cycle(r, bus);
        r.ctl.recovery.view(0).unwrap().phase != Phase::Ok
    });
    let recovered = found.and_then(|_| {
        (1..=max).find(|_| {
            cycle(r, bus);
            recovered(r, bus, 0)
        })
    });
    (found, recovered)
}

/// The recovery of a torque found off, after the check that found it: five transactions (the
/// Hardware Error read, the torque read, the re-anchor read, torque on, its check), each due at
/// once and run within RECOVERY_WAIT_CYCLES + 1 cycles of its predecessor's.
const RECOVERY_CYCLES_MAX: usize = 5 * (RECOVERY_WAIT_CYCLES as usize + 1);

/// The requests of the recovery (every one but the SyncWrite of the goals and the SyncRead).
fn recovery_requests(bus: &BusyBus) -> impl Iterator<Item = &Sent> {
    bus.sent.iter().filter(|s| s.instruction != SYNC_WRITE && !SYNC_READS.contains(&s.instruction))
}

#[test]
fn a_syncread_that_takes_most_of_the_cycle_does_not_starve_a_recovery() {
    // The SyncRead's replies 0.7 period after it: with the SyncWrite before it, less than a
    // quarter cycle is left before the bus's deadline (0.9 period) in every cycle.
    let (mut r, mut bus) = busy(&[1], 700_000, 20_000);
    for _ in 0..50 {
        cycle(&mut r, &mut bus);
    }
    let (found, took) = cycles_to_recover(&mut r, &mut bus, 2_000);
    let transactions = recovery_requests(&bus).count();
    // The round-robin checks torque every 100 ms (100 cycles), and its check waits for a slot too.
    let waits = (found, took, transactions);
    assert!(found.is_some_and(|n| n <= 100 + RECOVERY_WAIT_CYCLES as usize + 2), "found, recovered after, transactions: {waits:?}");
    assert!(took.is_some_and(|n| n <= RECOVERY_CYCLES_MAX), "found, recovered after, transactions: {waits:?}");
    assert!(r.bus.wire().torque_of(1));
    let deferred = r.shared.stats.reads_deferred.load(Ordering::Relaxed);
    assert!(deferred > 0 && deferred <= transactions as u64, "{deferred} SyncReads deferred for {transactions} transactions");
}

#[test]
fn a_silent_servo_that_makes_every_syncread_wait_out_its_deadline_does_not_starve_another_ones_recovery() {
    // Joint 2's cable is out: each SyncRead waits for it up to the bus's deadline (a failed read
    // is retried the next cycle, so with a divisor of 2 every cycle reads). Joint 1 browns out.
    for divisor in [1, 2, 3] {
        let (mut r, mut bus) = busy(&[1, 2], 100_000, 20_000);
        r.ctl.sync_read_divisor = divisor;
        for _ in 0..20 {
            cycle(&mut r, &mut bus);
        }
        bus.wire.wire().silent = vec![2];
        let (found, took) = cycles_to_recover(&mut r, &mut bus, 2_000);
        let checks = 2 * (100 + RECOVERY_WAIT_CYCLES as usize + 2);
        assert!(found.is_some_and(|n| n <= checks) && took.is_some_and(|n| n <= RECOVERY_CYCLES_MAX), "divisor {divisor}: {found:?} {took:?}");
        // A deferred read is made the next cycle: the reads stay at most a divisor apart (two
        // cycles at a divisor of 1: the deferred one's).
        let reads = syncread_per_cycle(&bus);
        let at: Vec<usize> = reads.iter().enumerate().filter(|(_, read)| **read).map(|(n, _)| n).collect();
        let gap = at.windows(2).map(|w| w[1] - w[0]).max();
        assert!(gap.is_some_and(|g| g <= divisor.max(2) as usize), "divisor {divisor}: SyncReads {gap:?} cycles apart");
        assert!(r.ctl.recovery.view(1).unwrap().silent && r.ctl.stop_request().is_none());
    }
}

#[test]
fn a_healthy_busy_bus_defers_a_syncread_only_for_a_torque_check() {
    // No fault: the recovery asks for nothing but the round-robin's torque check, every 100 ms.
    let (mut r, mut bus) = busy(&[1], 700_000, 20_000);
    for _ in 0..1_000 {
        cycle(&mut r, &mut bus);
    }
    let checks = recovery_requests(&bus).count() as u64;
    let deferred = r.shared.stats.reads_deferred.load(Ordering::Relaxed);
    assert!((9..=11).contains(&checks), "{checks} torque checks in 1 s");
    assert!(deferred <= checks, "{deferred} SyncReads deferred for {checks} torque checks");
}

#[test]
fn a_syncwrite_that_leaves_no_time_for_a_reply_defers_no_syncread() {
    // The SyncWrite alone leaves less than a quarter cycle: no recovery transaction can run, and
    // deferring the SyncRead would only lose it.
    let (mut r, mut bus) = busy(&[1], 100_000, 20_000);
    bus.sync_write_ns = 660_000;
    bus.wire.wire().set_torque(1, false);
    for _ in 0..300 {
        cycle(&mut r, &mut bus);
    }
    assert_eq!(r.shared.stats.reads_deferred.load(Ordering::Relaxed), 0);
    assert_eq!(recovery_requests(&bus).count(), 0, "no transaction without time for its reply");
    assert_eq!(r.shared.stats.sync_reads.load(Ordering::Relaxed), 300);
}

#[test]
fn a_quiet_bus_never_defers_a_syncread() {
    let (mut r, mut bus) = busy(&[1], 200_000, 20_000);
    for _ in 0..50 {
        cycle(&mut r, &mut bus);
    }
    let (found, took) = cycles_to_recover(&mut r, &mut bus, 2_000);
    assert!(found.is_some_and(|n| n <= 101) && took.is_some_and(|n| n <= 5), "{found:?} {took:?}");
    let cycles = r.shared.stats.cycles.load(Ordering::Relaxed);
    assert_eq!(r.shared.stats.sync_reads.load(Ordering::Relaxed), cycles, "a SyncRead every cycle");
    assert_eq!(r.shared.stats.reads_deferred.load(Ordering::Relaxed), 0);
}

/// Per cycle of `bus.sent`, whether it carried a SyncRead (cycles split at each SyncWrite).
fn syncread_per_cycle(bus: &BusyBus) -> Vec<bool> {
    let mut cycles = Vec::new();
    for s in &bus.sent {
        if s.instruction == SYNC_WRITE {
            cycles.push(false);
        } else if let (true, Some(read)) = (SYNC_READS.contains(&s.instruction), cycles.last_mut()) {
            *read = true;
        }
    }
    cycles
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]

    /// Whatever the SyncRead costs (up to what still lets it end before the bus's deadline),
    /// a recovery's transactions each get a slot within RECOVERY_WAIT_CYCLES + 1 cycles, none is
    /// started with less than a quarter cycle left for its reply, the SyncRead is never
    /// deferred two cycles in a row, and the joint that runs on is never taken for silent.
    #[test]
    fn a_requested_recovery_transaction_runs_within_a_bounded_number_of_cycles(
        sync_read_ns in 0u64..=820_000,
        packet_ns in 5_000u64..=40_000,
        warm_up in 1usize..150,
    ) {
        let (mut r, mut bus) = busy(&[1, 2], sync_read_ns, packet_ns);
        for _ in 0..warm_up {
            cycle(&mut r, &mut bus);
        }
        let (found, took) = cycles_to_recover(&mut r, &mut bus, 2_000);
        // The round-robin checks one joint's torque every 100 ms (counted from the check before),
        // in turn: joint 1's within two checks, each within a slot's wait (and a cycle's phase).
        let checks = 2 * (100 + RECOVERY_WAIT_CYCLES as usize + 2);
        proptest::prop_assert!(found.is_some_and(|n| n <= checks), "found after {:?} cycles", found);
        proptest::prop_assert!(took.is_some_and(|n| n <= RECOVERY_CYCLES_MAX), "recovered {:?} cycles after", took);
        for s in recovery_requests(&bus) {
            let left = s.deadline_ns.map(|d| d.saturating_sub(s.at_ns));
            proptest::prop_assert!(left.is_some_and(|l| l >= PERIOD / 4), "a transaction started with {:?} ns left", left);
        }
        let reads = syncread_per_cycle(&bus);
        proptest::prop_assert!(reads.windows(2).all(|w| w[0] || w[1]), "two cycles in a row without a SyncRead");
        let joint2 = r.ctl.recovery.view(1).unwrap();
        proptest::prop_assert!(!joint2.silent && joint2.counts.silences == 0 && joint2.phase == Phase::Ok);
        proptest::prop_assert!(r.ctl.stop_request().is_none());
    }
}
