//! The real-time admittance loop (Contract 5).
//!
//! A dedicated thread, optionally SCHED_FIFO with locked memory, runs one cycle per period of
//! a grid on CLOCK_MONOTONIC, started by a force sample's arrival (or at the end of the
//! period's window, or on the plain schedule), top to bottom like ros2's admittance_controller,
//! each step a named function of [`cycle::Controller`]:
//! newest force sample → tare, deadband, low-pass → joint torque → one admittance step
//! (`plant::admittance`) → state limits (anti-windup) → goal ticks → one SyncWrite → every
//! `sync_read_divisor` cycles a read of the present positions.
//!
//! Nothing in a cycle allocates, locks, logs or touches Python: force samples arrive through an
//! `rtrb` ring, parameter sets through a `triple_buffer`, telemetry leaves through another ring,
//! counters and histograms are atomics. Python validates parameter changes before publishing
//! them, and the loop ramps the gains towards each new set.
//!
//! - [`clock`]: the clock trait, CLOCK_MONOTONIC, the absolute-deadline pacer.
//! - [`doorbell`], [`trigger`]: a force sample's push wakes the loop; when a cycle starts.
//! - [`sched`]: SCHED_FIFO, mlockall, affinity, and their fallback report.
//! - [`histogram`]: fixed log-spaced timing histograms.
//! - [`sensor`], [`filter`]: force samples in, tare, deadband, low-pass.
//! - [`params`]: named parameters, validation, all-or-nothing sets.
//! - [`fault`]: the fault kinds, their bits and counters, and the loop's mode.
//! - [`joint`]: one joint's torque, limited integration and goal tick.
//! - [`compensation`]: the servo model inverted: the goal that makes the horn follow the model.
//! - [`passivity`]: the passivity guard: the port's energy, and a damping while the joint generates.
//! - [`bus`]: SyncWrite / SyncRead against a `Transport`.
//! - [`telemetry`]: the per-cycle record and the shared statistics.
//! - [`cycle`]: one cycle; [`runner`]: the paced loop; [`config`], [`handle`]: building,
//!   starting and steering a loop from another thread.
pub mod anchor;
pub mod bus;
pub mod clock;
pub mod compensation;
pub mod doorbell;
pub mod fault;
pub mod filter;
pub mod histogram;
pub mod joint;
pub mod params;
pub mod passivity;
pub mod sched;
pub mod sensor;
pub mod telemetry;
pub mod config;
pub mod cycle;
pub mod handle;
pub mod port;
pub mod recovery;
pub mod runner;
pub mod shared;
pub mod trigger;

pub use config::{JointConfig, LoopConfig};
pub use handle::{ForceSink, LoopHandle, StartError, StopPolicy};
pub use params::ParamValue;
pub use trigger::TriggerMode;
