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
    let mock = MockBus::new(bus, BusConfig { baudrate: BAUD, wire_delay: true, physics_rate_hz: 2000.0 }).unwrap();
    mock.start().unwrap();
    mock
}

fn client(mock: &MockBus, protocol: Protocol) -> Client<SerialPort> {
    let port = SerialPort::open(mock.port_path(), BAUD).unwrap();
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
