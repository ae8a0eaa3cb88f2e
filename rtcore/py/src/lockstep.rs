//! `run_lockstep`: the loop of a configuration and the servos of a `MockBus`, stepped together
//! in model time (dxlsim's `lockstep`: no wall clock, so the records are the same on every run
//! whatever the machine's load). bench/passivity.py judges the passivity guard with it.
use pyo3::prelude::*;

use dxlsim::daq::{ForceModel, HandProfile};
use dxlsim::lockstep::{run, LockstepHand, Stalls};

use crate::dxlsim::PyMockBus;
use crate::errors::config_error;
use crate::rt::{config_dict, loop_config, records_array};

/// Runs the loop `config` (the dict `AdmittanceLoop` takes) on `bus`'s servos (its thread not
/// started) for `seconds` of model time, the hand's muscle torque `tau` at `t` (repeated every
/// `period` if given, from `hand_delay_s`) on servo `hand_servo`, the sensor's counts and seeded
/// noise as the simulated DAQ's, and seeded stalls of the loop (`stall_probability` per cycle, up to
/// `stall_max_cycles` long); the telemetry records (`AdmittanceLoop.telemetry_dtype`).
#[pyfunction]
#[pyo3(signature = (config, bus, t, tau, period, seconds, *, hand_servo, lever_arm, axis, counts_per_newton,
                    noise_std_n=0.0, seed=1, hand_delay_s=0.5, stall_probability=0.0, stall_max_cycles=0))]
#[allow(clippy::too_many_arguments)]
fn run_lockstep<'py>(
    py: Python<'py>,
    config: &Bound<'py, PyAny>,
    bus: PyRef<'py, PyMockBus>,
    t: Vec<f64>,
    tau: Vec<f64>,
    period: Option<f64>,
    seconds: f64,
    hand_servo: u8,
    lever_arm: f64,
    axis: usize,
    counts_per_newton: Vec<f64>,
    noise_std_n: f64,
    seed: u64,
    hand_delay_s: f64,
    stall_probability: f64,
    stall_max_cycles: u32,
) -> PyResult<Bound<'py, PyAny>> {
    let config = loop_config(&config_dict(config)?)?;
    let (bus_config, running) = bus.bus_config();
    if running {
        return Err(config_error(py, "run_lockstep needs a MockBus whose thread is stopped (it alone moves the physics)"));
    }
    if !(hand_delay_s.is_finite() && hand_delay_s >= 0.0) {
        return Err(config_error(py, format!("hand_delay_s must be finite and >= 0, got {hand_delay_s}")));
    }
    let profile = HandProfile::new(t, tau, period).map_err(|e| config_error(py, e))?;
    let sensor = ForceModel { lever_arm, axis, counts_per_unit: counts_per_newton, bias_n: 0.0, noise_std_n };
    let stalls = Stalls { probability: stall_probability, max_cycles: stall_max_cycles };
    let hand = LockstepHand { profile, delay_s: hand_delay_s, servo: hand_servo, sensor, seed, stalls };
    let servos = bus.servos();
    let result = py.detach(|| run(&config, servos, bus_config, &hand, seconds));
    let done = result.map_err(|e| config_error(py, e))?;
    records_array(py, &done.records)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(run_lockstep, m)?)
}
