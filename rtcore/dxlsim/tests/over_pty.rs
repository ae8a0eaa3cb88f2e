//! The whole stack in Rust: the `dxl` client on the pty of a running `MockBus`, as the RT loop
//! uses it. Polls with deadlines; asserts where the horn goes, not how fast.
use std::time::{Duration, Instant};

use dxl::client::{Client, ClientError};
use dxl::serial::SerialPort;
use dxl::Protocol;
use dxlsim::{build_bus, BusConfig, MockBus, ServoConfig};
use plant::Params;

const BAUD: u32 = 1_000_000;

fn running_bus(protocol: Protocol) -> MockBus {
    let params = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..Params::default() };
    let configs = [1, 2].map(|id| ServoConfig { protocol, ..ServoConfig::new(id, params) }).to_vec();
    let bus = build_bus(configs, BAUD).expect("valid configuration");
    let mock = MockBus::new(bus, BusConfig { baudrate: BAUD, wire_delay: true, physics_rate_hz: 2000.0, rt_priority: 0 }).unwrap();
    mock.start().unwrap();
    mock
}

fn client(mock: &MockBus, protocol: Protocol) -> Client<SerialPort> {
    let port = SerialPort::open(&mock.port_path(), BAUD).unwrap();
    Client::new(port, protocol, Duration::from_millis(200))
}

#[test]
fn the_dxl_client_pings_reads_and_moves_a_p2_servo() {
    let mock = running_bus(Protocol::V2);
    let mut c = client(&mock, Protocol::V2);
    assert_eq!(c.ping(1).unwrap().model_number, 311);
    assert!(matches!(c.ping(9), Err(ClientError::Timeout { id: 9, .. })));
    c.write(2, 116, &3000i32.to_le_bytes()).unwrap();
    c.write(2, 64, &[1]).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut position = [0u8; 4];
    loop {
        c.read(2, 132, &mut position).unwrap();
        if (i32::from_le_bytes(position) - 3000).abs() <= 3 || Instant::now() > deadline {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!((i32::from_le_bytes(position) - 3000).abs() <= 3, "stopped at {}", i32::from_le_bytes(position));
    mock.stop().unwrap();
    assert!(mock.stats().bus.packets >= 5);
}

#[test]
fn the_dxl_client_reads_p1_servos() {
    let mock = running_bus(Protocol::V1);
    let mut c = client(&mock, Protocol::V1);
    assert_eq!(c.ping(2).unwrap().model_number, 310);
    let mut model = [0u8; 2];
    c.read(1, 0, &mut model).unwrap();
    assert_eq!(u16::from_le_bytes(model), 310);
    mock.stop().unwrap();
}

#[test]
fn stop_joins_and_start_resumes() {
    let mock = running_bus(Protocol::V2);
    mock.stop().unwrap();
    assert!(!mock.is_running());
    mock.start().unwrap();
    let mut c = client(&mock, Protocol::V2);
    assert_eq!(c.ping(2).unwrap().model_number, 311);
}

/// Polls `condition` every 10 ms until it holds or a generous deadline passes (a loaded machine).
fn wait_until(mut condition: impl FnMut() -> bool) -> bool {
    let deadline = Instant::now() + Duration::from_secs(20);
    while Instant::now() < deadline {
        if condition() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    condition()
}

#[test]
fn unplug_hangs_up_the_client_and_replug_brings_the_bus_back_at_the_same_link() {
    let mock = running_bus(Protocol::V2);
    let dir = std::env::temp_dir().join(format!("dxlsim-link-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("ttyDXL");
    mock.set_link(&link).unwrap();
    let first = mock.port_path();
    let mut c = Client::new(SerialPort::open(link.to_str().unwrap(), BAUD).unwrap(), Protocol::V2, Duration::from_millis(200));
    assert_eq!(c.ping(1).unwrap().model_number, 311);
    c.write(1, 64, &[1]).unwrap();
    assert!(mock.unplug());
    assert!(!mock.is_plugged() && !link.exists() && !std::path::Path::new(&first).exists(), "the device is gone");
    // The open descriptor is hung up: a write fails with EIO, a read sees the end of the file.
    assert!(matches!(c.ping(1), Err(ClientError::Io(_))));
    assert!(SerialPort::open(link.to_str().unwrap(), BAUD).is_err());
    assert!(mock.replug().unwrap());
    assert!(!mock.replug().unwrap(), "plugged in already");
    let mut c = Client::new(SerialPort::open(link.to_str().unwrap(), BAUD).unwrap(), Protocol::V2, Duration::from_millis(200));
    assert_eq!(c.ping(1).unwrap().model_number, 311);
    let mut torque = [0u8; 1];
    c.read(1, 64, &mut torque).unwrap();
    assert_eq!(torque, [1], "the servos kept their power and state");
    let stats = mock.stats().io;
    assert_eq!((stats.unplugs, stats.replugs), (1, 1));
    drop(mock);
    assert!(!link.exists(), "the link goes with the bus");
    let _ = std::fs::remove_dir(&dir);
}

#[test]
fn a_rebooted_servo_answers_then_boots_in_silence() {
    let mock = running_bus(Protocol::V2);
    let mut c = client(&mock, Protocol::V2);
    mock.lock().bus.servo_mut(1).unwrap().set_hardware_error(0x20);
    c.reboot(1).unwrap();
    assert!(matches!(c.ping(1), Err(ClientError::Timeout { id: 1, .. })), "booting");
    assert_eq!(c.ping(2).unwrap().model_number, 311, "the other servo is not affected");
    assert!(wait_until(|| c.ping(1).is_ok()));
    let mut error = [0xFFu8; 1];
    c.read(1, 70, &mut error).unwrap();
    assert_eq!(error, [0]);
    assert!(mock.stats().bus.silent_drops >= 1);
}

#[test]
fn a_browned_out_servo_is_silent_then_answers_with_torque_off() {
    let mock = running_bus(Protocol::V1);
    let mut c = client(&mock, Protocol::V1);
    c.write(2, 24, &[1]).unwrap();
    mock.lock().bus.servo_mut(2).unwrap().brown_out(0.3);
    assert!(matches!(c.ping(2), Err(ClientError::Timeout { id: 2, .. })));
    assert!(wait_until(|| c.ping(2).is_ok()));
    let mut torque = [0xFFu8; 1];
    c.read(2, 24, &mut torque).unwrap();
    assert_eq!(torque, [0], "RAM back to its defaults: torque off");
}

#[test]
fn an_alert_reaches_the_rust_client_as_a_real_servo_sends_it() {
    for protocol in [Protocol::V2, Protocol::V1] {
        let mock = running_bus(protocol);
        let mut c = client(&mock, protocol);
        mock.lock().bus.servo_mut(1).unwrap().set_hardware_error(0x24);
        let torque_address = if protocol == Protocol::V2 { 64 } else { 24 };
        let alert = c.write(1, torque_address, &[1]).unwrap().expect("a status packet");
        assert!(alert.alert() && !alert.is_failure(), "{protocol:?}: {alert:?}");
        let mut torque = [0xFFu8; 1];
        c.read(1, torque_address, &mut torque).unwrap();
        assert_eq!(torque, [0], "{protocol:?}: the shutdown keeps torque off");
    }
}

#[test]
fn the_bus_thread_reports_its_scheduling_and_how_late_its_replies_went_out() {
    let params = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..Params::default() };
    let bus = build_bus(vec![ServoConfig::new(1, params)], BAUD).expect("valid configuration");
    let config = BusConfig { baudrate: BAUD, wire_delay: true, physics_rate_hz: 2000.0, rt_priority: 10 };
    assert!(MockBus::new(build_bus(vec![ServoConfig::new(1, params)], BAUD).unwrap(), BusConfig { rt_priority: 100, ..config })
        .is_err(), "a priority beyond 99 is refused");
    let mock = MockBus::new(bus, config).unwrap();
    assert_eq!(mock.timing().rt.policy, "SCHED_OTHER", "nothing obtained before the thread runs");
    mock.start().unwrap();
    let mut c = client(&mock, Protocol::V2);
    for _ in 0..20 {
        c.ping(1).unwrap();
    }
    let timing = mock.timing();
    match timing.rt.policy {
        "SCHED_FIFO" => assert!(timing.rt.priority == 10 && timing.warnings.is_empty(), "{timing:?}"),
        _ => assert!(timing.warnings.len() == 1 && timing.warnings[0].contains("SCHED_FIFO"), "{timing:?}"),
    }
    assert_eq!(timing.reply_late_us.count, 20, "one lateness per reply");
    assert!(timing.wake_late_us.count > 0, "the idle thread's timed waits are measured");
    assert!(timing.reply_late_us.max >= 0.0 && timing.stalls <= timing.reply_late_us.count + timing.wake_late_us.count);
    mock.stop().unwrap();
}
