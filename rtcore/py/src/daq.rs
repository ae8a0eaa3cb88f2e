//! Python binding of `dxlsim::daq`: `SimulatedDaq`, the bench's OptoForce DAQ streaming from a
//! Rust thread (`admittance.mockbench.simulated_sensor.NativeOptoForce` wraps it).
use std::sync::atomic::Ordering;

use dxlsim::daq::{DaqConfig, ForceModel, HandProfile, SimulatedDaq};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::dxlsim::{PyMockBus, DEFAULT_RT_PRIORITY};
use crate::errors::{config_error, device_error};

/// A simulated OptoForce DAQ on a pseudo-terminal, pushing the hand's tabulated torque profile on
/// a servo of `bus` and streaming what the sensor reads (see docs/mock-bench.md).
#[pyclass(name = "SimulatedDaq", module = "admittance._rtcore", frozen)]
pub struct PySimulatedDaq {
    inner: SimulatedDaq,
}

#[pymethods]
impl PySimulatedDaq {
    #[new]
    #[pyo3(signature = (bus, hand_servo, t, tau, period, lever_arm, axis, counts_per_unit, bias_n=0.0,
                        noise_std_n=0.0, rate_hz=1000.0, seed=0, rt_priority=DEFAULT_RT_PRIORITY, link=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        bus: &PyMockBus,
        hand_servo: u8,
        t: Vec<f64>,
        tau: Vec<f64>,
        period: Option<f64>,
        lever_arm: f64,
        axis: usize,
        counts_per_unit: Vec<f64>,
        bias_n: f64,
        noise_std_n: f64,
        rate_hz: f64,
        seed: u64,
        rt_priority: i64,
        link: Option<std::path::PathBuf>,
    ) -> PyResult<Self> {
        let profile = HandProfile::new(t, tau, period).map_err(|e| config_error(py, e))?;
        let model = ForceModel { lever_arm, axis, counts_per_unit, bias_n, noise_std_n };
        let rt_priority = i32::try_from(rt_priority).unwrap_or(-1); // out of range: refused by `new`
        let config = DaqConfig { profile, model, hand_servo, rate_hz, seed, rt_priority };
        let inner = SimulatedDaq::new(config, bus.servos()).map_err(|e| config_error(py, e))?;
        if let Some(link) = link {
            inner.set_link(&link).map_err(|e| device_error(py, format!("cannot link {}: {e}", link.display())))?;
        }
        Ok(PySimulatedDaq { inner })
    }

    #[getter]
    fn port_path(&self) -> String {
        self.inner.port_path()
    }

    #[getter]
    fn link_path(&self) -> Option<String> {
        self.inner.link_path().map(|p| p.to_string_lossy().into_owned())
    }

    #[getter]
    fn plugged(&self) -> bool {
        self.inner.is_plugged()
    }

    fn start(&self, py: Python<'_>) -> PyResult<()> {
        self.inner.start().map_err(|e| device_error(py, format!("cannot start the simulated sensor's thread: {e}")))
    }

    /// Stops the stream and closes the pty for good (releases the GIL while the thread ends).
    fn close(&self, py: Python<'_>) {
        let inner = &self.inner;
        py.detach(|| inner.close());
    }

    fn unplug(&self) -> bool {
        self.inner.unplug()
    }

    fn replug(&self, py: Python<'_>) -> PyResult<bool> {
        self.inner.replug().map_err(|e| device_error(py, format!("cannot replug the simulated sensor: {e}")))
    }

    /// The hand keeps off the joint until `start_hand` (the daemon tares its sensor first).
    fn hold_hand(&self) {
        self.inner.state().hold_hand();
    }

    /// The hand starts its profile, from its beginning, `delay` seconds from now.
    fn start_hand(&self, py: Python<'_>, delay: f64) -> PyResult<()> {
        if !(delay.is_finite() && delay >= 0.0) {
            return Err(config_error(py, format!("the hand's delay must be a finite time ≥ 0 s, got {delay}")));
        }
        self.inner.state().start_hand(delay);
        Ok(())
    }

    /// A new tabulated profile for the hand, on the stream's time base.
    fn set_profile(&self, py: Python<'_>, t: Vec<f64>, tau: Vec<f64>, period: Option<f64>) -> PyResult<()> {
        self.inner.set_profile(HandProfile::new(t, tau, period).map_err(|e| config_error(py, e))?);
        Ok(())
    }

    #[pyo3(signature = (on=true))]
    fn silence(&self, on: bool) {
        self.inner.state().silent.store(on, Ordering::Relaxed);
    }

    #[pyo3(signature = (on=true))]
    fn saturate(&self, on: bool) {
        self.inner.state().saturated.store(on, Ordering::Relaxed);
    }

    fn set_status(&self, py: Python<'_>, bits: i64) -> PyResult<()> {
        let bits = u16::try_from(bits).map_err(|_| config_error(py, format!("an OptoForce status word is 16 bits, got {bits:#x}")))?;
        self.inner.state().fault_status.store(bits.into(), Ordering::Relaxed);
        Ok(())
    }

    fn inject_garbage(&self, py: Python<'_>, n_bytes: i64) -> PyResult<()> {
        if !(1..=4096).contains(&n_bytes) {
            return Err(config_error(py, format!("garbage is 1..4096 bytes, got {n_bytes}")));
        }
        self.inner.state().inject_garbage(n_bytes as u32);
        Ok(())
    }

    fn corrupt(&self, py: Python<'_>, n_frames: i64) -> PyResult<()> {
        if !(1..=100_000).contains(&n_frames) {
            return Err(config_error(py, format!("corrupt 1..100000 frames, got {n_frames}")));
        }
        self.inner.state().corrupt(n_frames as u32);
        Ok(())
    }

    /// The DAQ's counters and fault modes, named as the Python streaming mocks' `stats()`, with
    /// the thread's scheduling.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.inner.state();
        let n = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
        let d = PyDict::new(py);
        d.set_item("rate_hz", s.rate_hz())?;
        d.set_item("streaming", s.streaming())?;
        d.set_item("samples_sent", n(&s.samples_sent))?;
        d.set_item("samples_dropped", n(&s.samples_dropped))?;
        d.set_item("configs_received", n(&s.configs_received))?;
        d.set_item("late_skips", n(&s.late_skips))?;
        d.set_item("max_write_gap_ns", n(&s.max_write_gap_ns))?;
        d.set_item("silent", s.silent.load(Ordering::Relaxed))?;
        d.set_item("saturated", s.saturated.load(Ordering::Relaxed))?;
        d.set_item("fault_status", s.fault_status.load(Ordering::Relaxed))?;
        d.set_item("faulty_frames", n(&s.faulty_frames))?;
        d.set_item("last_torque", s.last_torque())?;
        let (unplugs, replugs) = self.inner.plug_counts();
        d.set_item("plugged", self.inner.is_plugged())?;
        d.set_item("unplugs", unplugs)?;
        d.set_item("replugs", replugs)?;
        let (rt, warnings) = self.inner.scheduling();
        d.set_item("policy", rt.policy)?;
        d.set_item("priority", rt.priority)?;
        d.set_item("warnings", warnings)?;
        Ok(d)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySimulatedDaq>()
}
