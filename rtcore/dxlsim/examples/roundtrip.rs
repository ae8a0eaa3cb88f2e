//! Ping round trips through the simulated bus, side by side: no timing emulation, wire time
//! only (Return Delay Time 0), and wire time plus the default Return Delay Time (500 µs).
//! Prints median / p99 / max per variant, and what each adds to the first variant's median
//! next to what the emulation should add, so the figures compare alternatives measured in one
//! run on the same (noisy) machine.
//!
//!     cargo run --release --example roundtrip -p admittance-dxlsim [-- N]
use std::time::{Duration, Instant};

use dxl::protocol2;
use dxl::serial::SerialPort;
use dxlsim::{build_bus, BusConfig, MockBus, ServoConfig};
use plant::Params;

const BAUD: u32 = 1_000_000;
const PING_REPLY_LEN: usize = 14;

fn bus(wire_delay: bool, return_delay: i64) -> MockBus {
    let params = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..Params::default() };
    let config = ServoConfig { registers: vec![("Return Delay Time".into(), return_delay)], ..ServoConfig::new(1, params) };
    let bus = build_bus(vec![config], BAUD).expect("a valid configuration");
    let config = BusConfig { baudrate: BAUD, wire_delay, physics_rate_hz: 2000.0, rt_priority: 0 };
    MockBus::new(bus, config).expect("a pseudo-terminal")
}

/// Round-trip times (µs) of `n` pings, sorted.
fn round_trips(mock: &MockBus, n: usize) -> std::io::Result<Vec<f64>> {
    mock.start()?;
    let port = SerialPort::open(&mock.port_path(), BAUD)?;
    let mut ping = [0u8; 16];
    let len = protocol2::encode_ping(&mut ping, 1).expect("ping fits");
    let mut reply = [0u8; 64];
    let mut times = Vec::with_capacity(n);
    for _ in 0..n {
        let start = Instant::now();
        port.write_all(&ping[..len])?;
        let mut got = 0;
        let deadline = start + Duration::from_millis(100);
        while got < PING_REPLY_LEN {
            let k = port.read(&mut reply[got..], deadline)?;
            if k == 0 {
                return Err(std::io::Error::new(std::io::ErrorKind::TimedOut, "no ping reply within 100 ms"));
            }
            got += k;
        }
        times.push(start.elapsed().as_secs_f64() * 1e6);
    }
    mock.stop()?;
    times.sort_by(f64::total_cmp);
    Ok(times)
}

/// What the emulation adds to a ping: the 10-byte instruction and 14-byte status on the wire
/// (10 bits per byte) plus the Return Delay Time (2 µs units).
fn expected_us(wire_delay: bool, return_delay: i64) -> f64 {
    if wire_delay {
        (10 + PING_REPLY_LEN) as f64 * 10.0 * 1e6 / BAUD as f64 + 2.0 * return_delay as f64
    } else {
        0.0
    }
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn main() -> std::io::Result<()> {
    let n: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(2000);
    let variants = [("instant (wire_delay off)", false, 250), ("wire time, RDT 0", true, 0), ("wire time + RDT 500 us", true, 250)];
    println!("ping round trip through the mock bus, {n} pings per variant, {BAUD} baud");
    println!("{:<26} {:>9} {:>9} {:>9} {:>12} {:>12}", "variant", "p50 us", "p99 us", "max us", "added p50", "expected");
    let mut base = None;
    for (name, wire_delay, rdt) in variants {
        let times = round_trips(&bus(wire_delay, rdt), n)?;
        let p50 = quantile(&times, 0.5);
        let added = p50 - *base.get_or_insert(p50);
        let (p99, max) = (quantile(&times, 0.99), times[times.len() - 1]);
        println!("{name:<26} {p50:>9.1} {p99:>9.1} {max:>9.1} {added:>12.1} {:>12.1}", expected_us(wire_delay, rdt));
    }
    Ok(())
}
