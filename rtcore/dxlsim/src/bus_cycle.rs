//! The loop's bus traffic of one cycle, timed on the in-process link (`bench/wire_limit.py`).
//!
//! One SyncWrite of every goal, then one present-position read (Sync Read or Fast Sync Read),
//! through the loop's own `JointBus` on a `DirectLink`, whose replies become readable only when
//! the wire model says (bytes at the baud rate, the Return Delay Time): the time from the write
//! to the read's last byte is the cycle's bus time as the loop sees it on the simulated bus,
//! the host's wake-ups included. The timing thread's timer slack is set to 1 ns meanwhile (the
//! loop's SCHED_FIFO thread has none; the default 50 µs would be measured as bus time).
use rt::bus::{JointBus, ReadChoice, Registers};
use rt::clock::monotonic_ns;

use crate::direct::DirectLink;

/// Protocol 2.0's Goal Position (116, 4 bytes), Present Position (132, 4) and Torque Enable (64)
/// on every model of the table.
const P2_REGISTERS: Registers =
    Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 };

/// What `time_bus_cycles` measured: each cycle's bus time (ns) and how many reads failed.
pub struct BusCycles {
    pub cycle_ns: Vec<u64>,
    pub failed_reads: u64,
}

/// Times `cycles` back-to-back bus cycles for the servos `ids` (Protocol 2.0), reading with
/// `read` (`Fast` or `Sync`; `Auto` is `Fast`). Each goal written is the servo's present tick,
/// so the horns stay where they are. A read gets `timeout_ns` before it counts as failed.
pub fn time_bus_cycles(link: &mut DirectLink, ids: &[u8], read: ReadChoice, cycles: usize, timeout_ns: u64) -> BusCycles {
    let mut bus = JointBus::new(dxl::Protocol::V2, P2_REGISTERS, ids);
    bus.choose_read(read, true);
    let mut goals: Vec<i64> = vec![2048; ids.len()];
    if let Ok(present) = bus.read_present(link, monotonic_ns() + timeout_ns) {
        goals.copy_from_slice(present);
    }
    let mut out = BusCycles { cycle_ns: Vec::with_capacity(cycles), failed_reads: 0 };
    // SAFETY: prctl with these options only reads/sets the calling thread's timer slack.
    let slack = unsafe { libc::prctl(libc::PR_GET_TIMERSLACK) };
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong) };
    for _ in 0..cycles {
        let start = monotonic_ns();
        let written = bus.write_goals(link, &goals).is_ok();
        if !(written && bus.read_present(link, start + timeout_ns).is_ok()) {
            out.failed_reads += 1;
        }
        out.cycle_ns.push(monotonic_ns().saturating_sub(start));
    }
    if slack > 0 {
        // SAFETY: as above; restores the caller's own slack.
        unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, slack as libc::c_ulong) };
    }
    out
}
