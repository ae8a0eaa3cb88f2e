//! `admittance._rtcore`: the one Python extension module of the Rust core.
//!
//! Each area registers its own classes and functions from its own file, so the binding layer
//! stays a thin newtype shell over the pure-Rust crates (pydantic-core/polars style):
//! - `plant.rs`: simulator (`Trial`, `simulate_batch`, ...)
//! - `servo.rs`: the servo's tracking dynamics (`ServoTrial`, `servo_simulate_batch`, `servo_lead`)
//! - `dxl.rs`: Dynamixel codec, model table, serial port
//! - `dxlsim.rs`: the simulated Dynamixel bus of the mock bench
//! - `daq.rs`: the mock bench's simulated force sensor, streaming from a Rust thread
//! - `rt.rs`: the real-time admittance loop
//! - `lockstep.rs`: that loop and the simulated bus in model time (the deterministic bench)
//! - `sensor.rs`: the Rust force-sensor readers feeding the loop
//! - `dict_fields.rs`: the configuration-dict rules `dxlsim.rs` and `rt.rs` share
use pyo3::prelude::*;

mod daq;
mod dict_fields;
mod dxl;
mod dxlsim;
mod errors;
mod lockstep;
mod plant;
mod rt;
mod sensor;
mod servo;

#[pymodule]
fn _rtcore(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("build_profile", if cfg!(debug_assertions) { "debug" } else { "release" })?;
    plant::register(m)?;
    dxl::register(m)?;
    dxlsim::register(m)?;
    daq::register(m)?;
    rt::register(m)?;
    servo::register(m)?;
    sensor::register(m)?;
    lockstep::register(m)?;
    Ok(())
}
