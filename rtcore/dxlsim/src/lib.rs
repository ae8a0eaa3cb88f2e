//! A simulated Dynamixel bus: MX-28/64/106 servos (Protocol 1.0 or 2.0 firmware) on a
//! pseudo-terminal, answering real packets, their horns moved by the rtcore plant.
//!
//! Layers, each testable alone:
//! - `table`: control-table memory with a real servo's access rules; `catalog` builds one from
//!   the `dxl` model table (the one source of addresses, shared with the driver);
//! - `motor`, `firmware`, `servo`: BAM's PWM/DC-motor model driving `plant::step`;
//! - `hand`: a hand gripping the horn (its impedance, what the sensor reads) and a horn that
//!   simply lags its goal (the bench's other servo);
//! - `request`, `bus`: packets → requests → replies, with Status Return Level, broadcast and
//!   error semantics; pure logic, no clock;
//! - `pty`, `server`: the pseudo-terminal and the thread that times replies and physics;
//! - `setup`: a bus from a configuration, every value checked first (the binding's entry);
//! - `bus_cycle`: the loop's SyncWrite + read timed on the in-process link (a bench's probe).
//!
//! Why a thread in Rust rather than a Python mock: the mock must answer within the SDK's
//! timeouts while the daemon's RT loop hammers it at 1 kHz, and step physics at 2 kHz; a
//! Python thread would share the GIL with the very code under test.
pub mod bus;
pub mod bus_cycle;
pub mod catalog;
pub mod daq;
pub mod direct;
pub mod firmware;
pub mod hand;
pub mod lockstep;
pub mod motor;
pub mod pty;
pub mod registers;
pub mod request;
pub mod server;
pub mod servo;
pub mod setup;
pub mod table;
pub mod units;
pub mod wire;

pub use bus::Bus;
pub use direct::DirectLink;
pub use server::{BusConfig, MockBus, Stats, TimingReport};
pub use servo::{Servo, ServoSpec, Snapshot};
pub use setup::{build_bus, ServoConfig};
