//! Python bindings of the `sensor` crate: `ForceReader`, a Rust force-sensor reader that
//! pushes straight into an `AdmittanceLoop`'s `ForceSink` (no sample passes through Python).
//!
//! Python drives its lifecycle, tare and event log only (`admittance/drivers/native_sensor.py`):
//! `start`/`stop`/`collect_raw` release the GIL; `stats`, `take_events` are O(counters).
use std::sync::RwLock;
use std::time::Duration;

use forceread::optoforce::{config_packet, Saturation};
use forceread::reader::{Reader, ReaderConfig, ReaderStats, Target};
use forceread::source::{CanFilter, SerialSource, SlcanSource, SocketCanSource, Source};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::dict_fields::{first_unknown_key, opt};
use crate::errors::{config_error, device_error};
use crate::rt::PyForceSink;

const READER_KEYS: [&str; 17] = [
    "transport", "port", "interface", "baudrate", "bitrate", "can_id", "open_delay_s", "rate_hz", "filter_hz",
    "tare_on_start", "counts_per_newton", "axes", "sensor_index", "saturation", "rt_priority", "stale_after_s", "extended",
];
const EXTENDED_ID_MAX: u32 = 0x1FFF_FFFF;
const STANDARD_ID_MAX: u32 = 0x7FF;

#[pyclass(name = "ForceReader", module = "admittance._rtcore", frozen)]
pub struct PyForceReader {
    inner: RwLock<Reader>,
}

fn key<'py, T: FromPyObjectOwned<'py>>(_py: Python<'py>, d: &Bound<'py, PyDict>, name: &str) -> PyResult<Option<T>> {
    opt(d, name, "sensor")
}

fn source_of(py: Python<'_>, d: &Bound<'_, PyDict>) -> PyResult<Box<dyn Source>> {
    let transport: String = key(py, d, "transport")?.unwrap_or_else(|| "serial".to_string());
    let port: String = key(py, d, "port")?.unwrap_or_default();
    let can_id: u32 = key(py, d, "can_id")?.unwrap_or(0x100);
    if can_id > EXTENDED_ID_MAX {
        return Err(config_error(py, format!("sensor: can_id {can_id:#x} is beyond 0x1FFFFFFF")));
    }
    let extended = key::<bool>(py, d, "extended")?.unwrap_or(can_id > STANDARD_ID_MAX);
    let filter = CanFilter { can_id, extended };
    match transport.as_str() {
        "serial" => {
            let baud: u32 = key(py, d, "baudrate")?.unwrap_or(1_000_000);
            let packet = match key::<u32>(py, d, "rate_hz")? {
                Some(rate) => {
                    let filter_hz: f64 = key(py, d, "filter_hz")?.unwrap_or(0.0);
                    let tare: bool = key(py, d, "tare_on_start")?.unwrap_or(false);
                    Some(config_packet(rate, filter_hz, tare).map_err(|e| config_error(py, e))?)
                }
                None => None,
            };
            Ok(Box::new(SerialSource::new(&port, baud, packet)))
        }
        "slcan" => {
            let tty_baud: u32 = key(py, d, "baudrate")?.unwrap_or(115_200);
            let bitrate: Option<u32> = key(py, d, "bitrate")?;
            let delay: f64 = key(py, d, "open_delay_s")?.unwrap_or(0.0);
            if !(0.0..=10.0).contains(&delay) {
                return Err(config_error(py, format!("sensor: open_delay_s must be within 0..10 s, got {delay}")));
            }
            let source = SlcanSource::new(&port, tty_baud, bitrate, Duration::from_secs_f64(delay), filter).map_err(|e| config_error(py, e))?;
            Ok(Box::new(source))
        }
        "socketcan" => {
            let interface: String = key(py, d, "interface")?.unwrap_or_default();
            Ok(Box::new(SocketCanSource::new(&interface, filter)))
        }
        other => Err(config_error(py, format!("sensor: transport {other:?} is not one of serial, slcan, socketcan"))),
    }
}

fn config_of(py: Python<'_>, d: &Bound<'_, PyDict>) -> PyResult<ReaderConfig> {
    let counts: Vec<f64> = key(py, d, "counts_per_newton")?.ok_or_else(|| config_error(py, "sensor: counts_per_newton is required"))?;
    let saturation: String = key(py, d, "saturation")?.unwrap_or_else(|| "hold".to_string());
    let stale_after_s: f64 = key(py, d, "stale_after_s")?.unwrap_or(0.2);
    if !(stale_after_s > 0.0 && stale_after_s <= 60.0) {
        return Err(config_error(py, format!("sensor: stale_after_s must be within (0, 60] s, got {stale_after_s}")));
    }
    let rt_priority: i32 = key(py, d, "rt_priority")?.unwrap_or(0);
    if !(0..=99).contains(&rt_priority) {
        return Err(config_error(py, format!("sensor: rt_priority must be within 0..99, got {rt_priority}")));
    }
    Ok(ReaderConfig {
        axes: key(py, d, "axes")?.unwrap_or(counts.len()),
        counts_per_unit: counts,
        sensor_index: key(py, d, "sensor_index")?.unwrap_or(0),
        saturation: Saturation::parse(&saturation).map_err(|e| config_error(py, e))?,
        rt_priority,
        stale_after_ns: (stale_after_s * 1e9) as u64,
    })
}

fn stats_dict<'py>(py: Python<'py>, s: &ReaderStats, reader: &Reader) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("reader", reader.path())?;
    d.set_item("state", s.state)?;
    d.set_item("error", s.error.clone())?;
    d.set_item("last_error", s.last_error.clone())?;
    for (name, value) in [
        ("samples_pushed", s.samples_pushed), ("samples_dropped", s.samples_dropped),
        ("dropped_before_open", s.dropped_before_open), ("last_sample_ns", s.last_sample_ns),
        ("disconnects", s.disconnects), ("reconnects", s.reconnects), ("reopen_failures", s.reopen_failures),
        ("stale_events", s.stale_events), ("max_gap_ns", s.max_gap_ns), ("max_gap_end_ns", s.max_gap.end_ns),
        ("max_gap_counter_before", u64::from(s.max_gap.counter_before)), ("max_gap_counter_after", u64::from(s.max_gap.counter_after)),
        ("batches", s.batches),
        ("frames", s.parser.frames), ("samples", s.parser.samples), ("acks", s.parser.acks),
        ("checksum_errors", s.parser.checksum_errors), ("resyncs", s.parser.resyncs), ("skipped_bytes", s.parser.skipped_bytes),
        ("status_faults", s.converter.status_faults), ("overloads", s.converter.overloads),
        ("unexpected_frames", s.converter.unexpected_frames), ("counter_gaps", s.converter.counter_gaps),
        ("ack_errors", s.converter.ack_errors), ("can_frames", s.can.can_frames), ("foreign_frames", s.can.foreign_frames),
        ("undecodable_frames", s.can.undecodable_frames), ("slcan_refused_commands", s.can.refused_commands),
    ] {
        d.set_item(name, value)?;
    }
    d.set_item("stale", s.stale)?;
    d.set_item("thread_policy", s.thread_policy)?;
    d.set_item("thread_priority", s.thread_priority)?;
    d.set_item("thread_warnings", s.thread_warnings.clone())?;
    Ok(d)
}

#[pymethods]
impl PyForceReader {
    /// `config`: transport ("serial", "slcan", "socketcan") and its keys (docs/sensors.md);
    /// `sink`: the loop's `ForceSink`, or None to capture samples for `take_captured()`.
    #[new]
    #[pyo3(signature = (config, sink=None))]
    fn new(py: Python<'_>, config: &Bound<'_, PyDict>, sink: Option<PyRef<'_, PyForceSink>>) -> PyResult<Self> {
        if let Some(unknown) = first_unknown_key(config, &READER_KEYS, "sensor")? {
            return Err(config_error(py, format!("sensor: unknown key {unknown:?}")));
        }
        let source = source_of(py, config)?;
        let reader_config = config_of(py, config)?;
        let target = match sink {
            Some(s) => Target::Loop(s.inner.clone()),
            None => Target::Capture,
        };
        let reader = Reader::new(source, reader_config, target).map_err(|e| config_error(py, e))?;
        Ok(PyForceReader { inner: RwLock::new(reader) })
    }

    /// Open the device (DeviceError naming it when missing) and start the reader thread.
    fn start(&self, py: Python<'_>) -> PyResult<()> {
        let result = py.detach(|| self.inner.write().map_err(|_| "the reader's lock is poisoned".to_string()).and_then(|mut r| r.start()));
        result.map_err(|e| device_error(py, e))
    }

    fn stop(&self, py: Python<'_>) {
        py.detach(|| {
            if let Ok(mut r) = self.inner.write() {
                r.stop();
            }
        });
    }

    #[getter]
    fn running(&self) -> bool {
        self.inner.read().map(|r| r.running()).unwrap_or(false)
    }

    #[getter]
    fn path(&self) -> &'static str {
        self.inner.read().map(|r| r.path()).unwrap_or("rust")
    }

    fn describe(&self) -> String {
        self.inner.read().map(|r| r.describe().to_string()).unwrap_or_default()
    }

    /// Let samples through to the loop's ring (before, they only feed a tare).
    fn open_gate(&self) {
        if let Ok(r) = self.inner.read() {
            r.open_gate();
        }
    }

    fn set_stale_after(&self, py: Python<'_>, seconds: f64) -> PyResult<()> {
        if !(seconds > 0.0 && seconds <= 60.0) {
            return Err(config_error(py, format!("stale_after_s must be within (0, 60] s, got {seconds}")));
        }
        if let Ok(r) = self.inner.read() {
            r.set_stale_after_ns((seconds * 1e9) as u64);
        }
        Ok(())
    }

    fn set_bias(&self, py: Python<'_>, bias: [f64; 6]) -> PyResult<()> {
        let r = self.inner.read().map_err(|_| config_error(py, "the reader's lock is poisoned"))?;
        r.set_bias(bias).map_err(|e| config_error(py, e))
    }

    #[getter]
    fn bias(&self) -> [f64; 6] {
        self.inner.read().map(|r| r.bias()).unwrap_or([0.0; 6])
    }

    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let r = self.inner.read().map_err(|_| config_error(py, "the reader's lock is poisoned"))?;
        stats_dict(py, &r.stats(), &r)
    }

    /// The events since the last call: [(kind, message)], oldest first.
    fn take_events(&self) -> Vec<(&'static str, String)> {
        self.inner.read().map(|r| r.take_events()).unwrap_or_default()
    }

    /// Captured samples (no sink given): [(t_ns, [fx, fy, fz, tx, ty, tz])].
    fn take_captured<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let samples = self.inner.read().map(|r| r.take_captured()).unwrap_or_default();
        PyList::new(py, samples.iter().map(|s| (s.t_ns, s.forces.to_vec())))
    }

    /// The next `n` raw samples (bias not removed), waiting up to `timeout_s`.
    fn collect_raw(&self, py: Python<'_>, n: usize, timeout_s: f64) -> Vec<[f64; 6]> {
        let timeout = Duration::from_secs_f64(if timeout_s.is_finite() { timeout_s.clamp(0.0, 3600.0) } else { 0.0 });
        py.detach(|| self.inner.read().map(|r| r.collect_raw(n, timeout)).unwrap_or_default())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyForceReader>()
}
