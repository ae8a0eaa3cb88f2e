//! The in-process link as the RT loop uses it: the loop's own `JointBus` on a `DirectLink` to a
//! running `MockBus`. Replies come when the wire model says, never before; unplug and replug
//! act on it as on the pty.
use std::time::Duration;

use dxl::Protocol;
use dxlsim::{build_bus, BusConfig, MockBus, ServoConfig};
use plant::Params;
use rt::bus::{link_gone, JointBus, Registers, Transport};
use rt::clock::monotonic_ns;

const BAUD: u32 = 57_600; // slow enough that the wire time is far above any scheduling noise

fn running_bus() -> MockBus {
    let params = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..Params::default() };
    let configs = [1, 2].map(|id| ServoConfig { protocol: Protocol::V2, ..ServoConfig::new(id, params) }).to_vec();
    let bus = build_bus(configs, BAUD).expect("valid configuration");
    let mock = MockBus::new(bus, BusConfig { baudrate: BAUD, wire_delay: true, physics_rate_hz: 2000.0, rt_priority: 0 }).unwrap();
    mock.start().unwrap();
    mock
}

fn regs() -> Registers {
    Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 }
}

#[test]
fn a_sync_read_is_answered_no_sooner_than_the_wire_allows() {
    let mock = running_bus();
    let mut link = mock.direct_link();
    let mut bus = JointBus::new(Protocol::V2, regs(), &[1, 2]);
    let sent = monotonic_ns();
    let present = bus.read_present(&mut link, sent + 100_000_000).unwrap().to_vec();
    let took = monotonic_ns() - sent;
    assert_eq!(present.len(), 2);
    // SyncRead of two: 14 + 2 bytes out, two 15-byte statuses back, 10 bits a byte at 57600 baud.
    let wire_ns = (16 + 2 * 15) * 10 * 1_000_000_000 / u64::from(BAUD);
    assert!(took >= wire_ns, "answered after {took} ns, the wire alone takes {wire_ns} ns");
    assert!(mock.stats().bus.packets >= 1);
}

#[test]
fn a_reply_not_yet_due_is_not_readable_and_a_silent_servo_times_out() {
    let mock = running_bus();
    let mut link = mock.direct_link();
    let mut bus = JointBus::new(Protocol::V2, regs(), &[1, 3]); // 3 is not on the bus
    assert!(bus.read_torque_enable(&mut link, 0, monotonic_ns() + 100_000_000).is_ok());
    assert!(bus.read_torque_enable(&mut link, 1, monotonic_ns() + 5_000_000).is_err(), "nobody answers for ID 3");
    // A PING written now: its reply is on the wire for over a millisecond at this baud rate.
    let sent = monotonic_ns();
    link.write_all(&[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E]).unwrap();
    let mut buf = [0u8; 64];
    let early = link.read_until(&mut buf, 0).unwrap();
    // 10 bytes out and 14 back, 10 bits a byte: only a test thread preempted that long may see it.
    let wire_ns = (10 + 14) * 10 * 1_000_000_000 / u64::from(BAUD);
    if monotonic_ns() < sent + wire_ns {
        assert_eq!(early, 0, "not due yet");
    }
    let n = if early > 0 { early } else { link.read_until(&mut buf, monotonic_ns() + 100_000_000).unwrap() };
    assert!(n >= 11 && buf[4] == 1 && buf[7] == 0x55, "{:?}", &buf[..n]);
}

#[test]
fn unplug_fails_the_link_with_eio_and_replug_brings_it_back() {
    let mock = running_bus();
    let mut link = mock.direct_link();
    let mut bus = JointBus::new(Protocol::V2, regs(), &[1]);
    assert!(mock.unplug());
    let error = link.write_all(&[0xFF]).unwrap_err();
    assert!(link_gone(&error), "{error}");
    assert!(!link.reconnect(), "still unplugged");
    assert!(mock.replug().unwrap());
    assert!(link.reconnect(), "back on the new adapter");
    let deadline = monotonic_ns() + Duration::from_millis(100).as_nanos() as u64;
    assert_eq!(bus.read_present(&mut link, deadline).unwrap().len(), 1);
    // A replug the client did not see (no reconnect in between) breaks its link once.
    assert!(mock.unplug() && mock.replug().unwrap());
    assert!(link_gone(&link.write_all(&[0xFF]).unwrap_err()));
    assert!(link.reconnect());
}

#[test]
fn a_fast_sync_read_after_a_sync_write_waits_for_its_bytes_and_one_return_delay() {
    let mock = running_bus();
    let mut link = mock.direct_link();
    let mut bus = JointBus::new(Protocol::V2, regs(), &[1, 2]);
    bus.choose_read(rt::bus::ReadChoice::Fast, true);
    let sent = monotonic_ns();
    bus.write_goals(&mut link, &[2048, 2048]).unwrap();
    let present = bus.read_present(&mut link, sent + 200_000_000).unwrap().to_vec();
    let took = monotonic_ns() - sent;
    assert_eq!((present.len(), bus.read_name()), (2, "fast_sync_read"));
    // SyncWrite 14 + 2·5 bytes, then the Fast Sync Read 14 + 2 bytes, one after the other on
    // the wire, then one 500 µs Return Delay Time and the 8 + 2·8-byte combined reply.
    let wire_ns = (24 + 16 + 24) * 10 * 1_000_000_000 / u64::from(BAUD) + 500_000;
    assert!(took >= wire_ns, "answered after {took} ns, the wire alone takes {wire_ns} ns");
}
