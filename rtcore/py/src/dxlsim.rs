//! Python bindings of the `dxlsim` crate: `MockBus` (docs/architecture.md, Contract 4).
//!
//! Servos are described by plain dicts so a TOML configuration maps onto them directly.
//! Every key is checked (an unknown key is a typo, not something to ignore) and every
//! configuration error is an `admittance.errors.ConfigError` with one clear line; `stop()`
//! and the blocking calls release the GIL so the bus thread, which never takes it, can finish.
use std::collections::HashMap;

use dxl::Protocol;
use dxlsim::servo::Snapshot;
use dxlsim::{build_bus, BusConfig, MockBus, ServoConfig};
use plant::{param_index, FrictionLaw, Load, Params, PARAM_NAMES};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use crate::dict_fields::{first_unknown_key, opt};
use crate::rt::percentiles;
use crate::errors::{config_error, device_error};

/// The keys a servo dict may have.
const SERVO_KEYS: [&str; 18] = [
    "id",
    "model",
    "protocol",
    "params",
    "load_inertia",
    "gravity_torque",
    "friction",
    "kt",
    "resistance",
    "input_voltage",
    "initial_theta",
    "ambient_temperature",
    "registers",
    "name",
    "first_order_lag",
    "reboot_time_s",
    "overload_time_s",
    "fast_sync_read",
];

/// `key` of a servo dict as `T`, or `default` when absent.
fn field<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, key: &str, default: T) -> PyResult<T> {
    Ok(opt(d, key, "servo")?.unwrap_or(default))
}

fn plant_params(d: &Bound<'_, PyDict>, id: u8) -> PyResult<Params> {
    let py = d.py();
    let Some(obj) = d.get_item("params")? else {
        return Err(config_error(py, format!("servo {id}: \"params\" is required (at least motor_inertia)")));
    };
    let given: HashMap<String, f64> = obj
        .extract()
        .map_err(|e| config_error(py, format!("servo {id}: \"params\" must map names to numbers: {e}")))?;
    let mut values = Params::default().to_array();
    for (name, value) in given {
        let k = param_index(&name).ok_or_else(|| {
            config_error(py, format!("servo {id}: unknown plant parameter {name:?} (known: {})", PARAM_NAMES.join(", ")))
        })?;
        values[k] = value;
    }
    Params::from_slice(&values).map_err(|e| config_error(py, e.to_string()))
}

fn servo_config(d: &Bound<'_, PyDict>) -> PyResult<ServoConfig> {
    let py = d.py();
    if let Some(key) = first_unknown_key(d, &SERVO_KEYS, "servo")? {
        return Err(config_error(py, format!("unknown servo key {key:?} (known: {})", SERVO_KEYS.join(", "))));
    }
    let id: i64 = d
        .get_item("id")?
        .ok_or_else(|| config_error(py, "every servo needs an \"id\""))?
        .extract()
        .map_err(|_| config_error(py, "servo \"id\" must be an integer"))?;
    let id = u8::try_from(id).map_err(|_| config_error(py, format!("servo ID {id} is out of range")))?;
    let protocol_number: u8 = field(d, "protocol", 2)?;
    let protocol = Protocol::from_number(protocol_number)
        .ok_or_else(|| config_error(py, format!("servo {id}: protocol must be 1 or 2, got {protocol_number}")))?;
    let friction: String = field(d, "friction", "stick".to_string())?;
    let friction: FrictionLaw = friction.parse().map_err(|e: plant::PlantError| config_error(py, e.to_string()))?;
    let registers: HashMap<String, i64> = field(d, "registers", HashMap::new())?;
    let defaults = ServoConfig::new(id, Params::default());
    Ok(ServoConfig {
        id,
        model: field(d, "model", defaults.model)?,
        protocol,
        params: plant_params(d, id)?,
        load: Load { inertia: field(d, "load_inertia", 0.0)?, gravity_torque: field(d, "gravity_torque", 0.0)? },
        friction,
        kt: field(d, "kt", None)?,
        resistance: field(d, "resistance", None)?,
        input_voltage: field(d, "input_voltage", defaults.input_voltage)?,
        initial_theta: field(d, "initial_theta", defaults.initial_theta)?,
        ambient_temperature: field(d, "ambient_temperature", defaults.ambient_temperature)?,
        registers: registers.into_iter().collect(),
        first_order_lag: field(d, "first_order_lag", None)?,
        reboot_time_s: field(d, "reboot_time_s", defaults.reboot_time_s)?,
        overload_time_s: field(d, "overload_time_s", None)?,
        fast_sync_read: field(d, "fast_sync_read", true)?,
    })
}

/// The `servos` argument: a sequence of dicts.
fn servo_configs(servos: &Bound<'_, PyAny>) -> PyResult<Vec<ServoConfig>> {
    let py = servos.py();
    let not_a_list = || config_error(py, "servos must be a list of servo tables (dicts)");
    if servos.is_instance_of::<pyo3::types::PyString>() || servos.is_instance_of::<PyDict>() {
        return Err(not_a_list());
    }
    let mut configs = Vec::new();
    for item in servos.try_iter().map_err(|_| not_a_list())? {
        let item = item?;
        let table = item.cast::<PyDict>().map_err(|_| {
            config_error(py, format!("each servo must be a table (dict), got {}", item.get_type().name().map_or("?".into(), |n| n.to_string())))
        })?;
        configs.push(servo_config(table)?);
    }
    Ok(configs)
}

fn snapshot_dict<'py>(py: Python<'py>, s: &Snapshot) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("theta", s.theta)?;
    d.set_item("omega", s.omega)?;
    d.set_item("goal_tick", s.goal_tick)?;
    d.set_item("present_tick", s.present_tick)?;
    d.set_item("torque_enabled", s.torque_enabled)?;
    d.set_item("duty", s.duty)?;
    d.set_item("motor_torque", s.motor_torque)?;
    d.set_item("external_torque", s.external_torque)?;
    d.set_item("hand_torque", s.hand_torque)?;
    d.set_item("temperature", s.temperature)?;
    d.set_item("hardware_error", s.hardware_error)?;
    d.set_item("time", s.time)?;
    d.set_item("silent", s.silent)?;
    Ok(d)
}

/// A simulated Dynamixel bus on a pseudo-terminal (see docs/mock-bench.md).
#[pyclass(name = "MockBus", module = "admittance._rtcore", frozen)]
pub struct PyMockBus {
    inner: MockBus,
}

impl PyMockBus {
    /// An in-process link to these servos (the embedded bench's loop).
    pub(crate) fn direct_link(&self) -> dxlsim::DirectLink {
        self.inner.direct_link()
    }

    /// The bus's wire and physics settings, and whether its thread runs (the lockstep bench's).
    pub(crate) fn bus_config(&self) -> (dxlsim::BusConfig, bool) {
        (self.inner.config(), self.inner.is_running())
    }

    /// The servos' shared state (the simulated sensor pushes the hand on them).
    pub(crate) fn servos(&self) -> std::sync::Arc<std::sync::Mutex<dxlsim::server::Shared>> {
        self.inner.servos()
    }

    fn with_servo<T>(&self, py: Python<'_>, id: u8, f: impl FnOnce(&mut dxlsim::Servo) -> T) -> PyResult<T> {
        let mut shared = self.inner.lock();
        match shared.bus.servo_mut(id) {
            Some(servo) => Ok(f(servo)),
            None => Err(config_error(py, format!("no servo with ID {id} on this bus"))),
        }
    }
}

#[pymethods]
impl PyMockBus {
    #[new]
    #[pyo3(signature = (servos, baudrate=1_000_000, wire_delay=true, physics_rate_hz=2000.0, link_path=None,
                        rt_priority=DEFAULT_RT_PRIORITY))]
    fn new(
        py: Python<'_>,
        servos: &Bound<'_, PyAny>,
        baudrate: i64,
        wire_delay: bool,
        physics_rate_hz: f64,
        link_path: Option<std::path::PathBuf>,
        rt_priority: i64,
    ) -> PyResult<Self> {
        if !(physics_rate_hz.is_finite() && (100.0..=100_000.0).contains(&physics_rate_hz)) {
            return Err(config_error(py, format!("physics_rate_hz must be within 100..=100000, got {physics_rate_hz}")));
        }
        let rt_priority = i32::try_from(rt_priority)
            .ok()
            .filter(|p| (0..=99).contains(p))
            .ok_or_else(|| config_error(py, format!("rt_priority must be within 0..=99 (0 = SCHED_OTHER), got {rt_priority}")))?;
        let baudrate = u32::try_from(baudrate)
            .ok()
            .filter(|b| *b > 0)
            .ok_or_else(|| config_error(py, format!("baudrate must be a positive bit rate, got {baudrate}")))?;
        let configs = servo_configs(servos)?;
        let bus = build_bus(configs, baudrate).map_err(|e| config_error(py, e))?;
        let config = BusConfig { baudrate, wire_delay, physics_rate_hz, rt_priority };
        let inner = MockBus::new(bus, config)
            .map_err(|e| device_error(py, format!("cannot open a pseudo-terminal for the mock bus: {e}")))?;
        if let Some(link) = link_path {
            inner
                .set_link(&link)
                .map_err(|e| device_error(py, format!("cannot make the mock bus's link {}: {e}", link.display())))?;
        }
        Ok(PyMockBus { inner })
    }

    /// The device a client opens now, e.g. "/dev/pts/7" (a new one after each replug).
    #[getter]
    fn port_path(&self) -> String {
        self.inner.port_path()
    }

    /// The stable symlink to the pty (None unless `link_path` was given): the same across
    /// replugs, absent while unplugged.
    #[getter]
    fn link_path(&self) -> Option<String> {
        self.inner.link_path().map(|p| p.to_string_lossy().into_owned())
    }

    #[getter]
    fn plugged(&self) -> bool {
        self.inner.is_plugged()
    }

    /// Pulls the USB adapter out: the pty closes, so a client's open descriptor hangs up (reads
    /// end, writes fail with EIO) and the device node and the link disappear. The servos keep
    /// their power and state. False if it was unplugged already.
    fn unplug(&self, py: Python<'_>) -> bool {
        let inner = &self.inner;
        py.detach(|| inner.unplug())
    }

    /// Puts the adapter back: a new pty, the link pointed at it. False if plugged in already.
    fn replug(&self, py: Python<'_>) -> PyResult<bool> {
        self.inner.replug().map_err(|e| device_error(py, format!("cannot replug the mock bus: {e}")))
    }

    #[getter]
    fn running(&self) -> bool {
        self.inner.is_running()
    }

    /// The Dynamixel protocol of the bus (1 or 2).
    #[getter]
    fn protocol(&self) -> u8 {
        self.inner.lock().bus.protocol().number()
    }

    fn start(&self, py: Python<'_>) -> PyResult<()> {
        self.inner.start().map_err(|e| device_error(py, format!("cannot start the mock bus thread: {e}")))
    }

    /// Stops the bus thread and joins it (without the GIL).
    fn stop(&self, py: Python<'_>) -> PyResult<()> {
        let inner = &self.inner;
        py.detach(|| inner.stop()).map_err(|e| device_error(py, format!("the mock bus thread failed: {e}")))
    }

    /// The loop's bus traffic of `cycles` cycles on the in-process link (`bench/wire_limit.py`):
    /// per cycle, a SyncWrite of every goal then one read of the present positions of `ids`
    /// with `read` ("fast" or "sync"), timed from the write to the read's last byte. Returns
    /// (each cycle's bus time in ns, reads that failed). Protocol 2.0 buses only.
    #[pyo3(signature = (ids, read, cycles, timeout_ms=50.0))]
    fn time_bus_cycles(&self, py: Python<'_>, ids: Vec<u8>, read: &str, cycles: usize, timeout_ms: f64) -> PyResult<(Vec<u64>, u64)> {
        let choice = match rt::bus::ReadChoice::parse(read) {
            Some(c @ (rt::bus::ReadChoice::Fast | rt::bus::ReadChoice::Sync)) => c,
            _ => return Err(config_error(py, format!("read must be \"fast\" or \"sync\", got {read:?}"))),
        };
        if self.inner.lock().bus.protocol() != Protocol::V2 || ids.is_empty() || !(timeout_ms > 0.0 && timeout_ms <= 1e4) {
            return Err(config_error(py, "a Protocol 2.0 bus, at least one ID and 0 < timeout_ms <= 10000 are needed"));
        }
        let mut link = self.inner.direct_link();
        let timeout_ns = (timeout_ms * 1e6) as u64;
        let timed = py.detach(|| dxlsim::bus_cycle::time_bus_cycles(&mut link, &ids, choice, cycles.min(1_000_000), timeout_ns));
        Ok((timed.cycle_ns, timed.failed_reads))
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyResult<PyRef<'_, Self>> {
        slf.start(slf.py())?;
        Ok(slf)
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, py: Python<'_>, _args: &Bound<'_, PyTuple>) -> PyResult<bool> {
        self.stop(py)?;
        Ok(false)
    }

    /// The hand / disturbance torque on a horn (N·m), held until changed.
    fn set_external_torque(&self, py: Python<'_>, id: u8, tau: f64) -> PyResult<()> {
        if !tau.is_finite() {
            return Err(config_error(py, format!("external torque must be finite, got {tau}")));
        }
        self.with_servo(py, id, |s| s.set_external_torque(tau))
    }

    /// A hand grips the horn where it is now: its inertia (kg·m²) rides with the horn, its
    /// damping (N·m·s/rad) and stiffness (N·m/rad) pull it back; `set_external_torque` is then the
    /// muscle's torque and `servo_state(id)["hand_torque"]` what a sensor between them reads.
    /// All zero lets go (the external torque acts alone again).
    #[pyo3(signature = (id, inertia=0.0, damping=0.0, stiffness=0.0))]
    fn set_hand(&self, py: Python<'_>, id: u8, inertia: f64, damping: f64, stiffness: f64) -> PyResult<()> {
        let off = inertia == 0.0 && damping == 0.0 && stiffness == 0.0;
        let result = self.with_servo(py, id, |s| {
            let hand = if off { None } else { Some(dxlsim::hand::Hand::new(inertia, damping, stiffness, s.snapshot().theta)?) };
            s.set_hand(hand);
            Ok::<(), String>(())
        })?;
        result.map_err(|e| config_error(py, e))
    }

    /// Raises Hardware Error Status bits (P2 layout: 0x01 voltage, 0x04 overheating, 0x08
    /// encoder, 0x10 electrical shock, 0x20 overload); 0 clears them (P1 has no reboot).
    fn set_hardware_error(&self, py: Python<'_>, id: u8, bits: u8) -> PyResult<()> {
        self.with_servo(py, id, |s| s.set_hardware_error(bits))
    }

    /// A brown-out: the servo resets as at power-up (RAM registers back to their defaults,
    /// torque off, errors cleared) and stays silent for `seconds` while it boots.
    fn brown_out(&self, py: Python<'_>, id: u8, seconds: f64) -> PyResult<()> {
        if !(seconds.is_finite() && (0.0..=60.0).contains(&seconds)) {
            return Err(config_error(py, format!("a brown-out lasts 0..=60 s, got {seconds}")));
        }
        self.with_servo(py, id, |s| s.brown_out(seconds))
    }

    /// An encoder glitch: a read of Present Position reports `offset` ticks more, the next one
    /// only (`every` 0) or every `every`-th read until cleared (`offset` 0).
    #[pyo3(signature = (id, offset, every=0))]
    fn glitch_position(&self, py: Python<'_>, id: u8, offset: i64, every: u32) -> PyResult<()> {
        if offset.abs() > 1 << 20 || every > 1000 {
            return Err(config_error(py, format!("a glitch is at most ±{} ticks, every 0..=1000 reads", 1 << 20)));
        }
        self.with_servo(py, id, |s| s.glitch_position(offset, every))
    }

    /// Torque Enable cleared with no error bit (torque found off).
    fn torque_off(&self, py: Python<'_>, id: u8) -> PyResult<()> {
        self.with_servo(py, id, |s| s.torque_off())
    }

    /// The horn's simulated state: theta, omega, goal_tick, present_tick and more.
    fn servo_state<'py>(&self, py: Python<'py>, id: u8) -> PyResult<Bound<'py, PyDict>> {
        let snapshot = self.with_servo(py, id, |s| s.snapshot())?;
        snapshot_dict(py, &snapshot)
    }

    /// A control-table item's value by its e-manual name (e.g. "Present Position").
    fn register(&self, py: Python<'_>, id: u8, name: &str) -> PyResult<i64> {
        self.with_servo(py, id, |s| s.table.get(name))?
            .ok_or_else(|| config_error(py, format!("servo {id} has no control-table item {name:?}")))
    }

    /// Counters of packets, replies, errors and I/O since construction.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.inner.stats();
        let d = PyDict::new(py);
        let entries = [
            ("packets", s.bus.packets),
            ("replies", s.bus.replies),
            ("crc_errors", s.bus.crc_errors),
            ("unknown_instructions", s.bus.unknown_instructions),
            ("malformed", s.bus.malformed),
            ("table_errors", s.bus.table_errors),
            ("absent_ids", s.bus.absent_ids),
            ("silent_drops", s.bus.silent_drops),
            ("unplugs", s.io.unplugs),
            ("replugs", s.io.replugs),
            ("bytes_in", s.io.bytes_in),
            ("bytes_out", s.io.bytes_out),
            ("garbage_bytes", s.io.garbage_bytes),
            ("framing_errors", s.io.framing_errors),
            ("foreign_status_packets", s.io.foreign_status_packets),
            ("dropped_reply_bytes", s.io.dropped_reply_bytes),
            ("truncated_packets", s.io.truncated_packets),
            ("physics_steps", s.io.physics_steps),
            ("skipped_steps", s.io.skipped_steps),
        ];
        for (key, value) in entries {
            d.set_item(key, value)?;
        }
        Ok(d)
    }

    /// How late the bus thread ran by its own clock, and its scheduling: `reply_late_us` (each
    /// reply's write behind its due time) and `wake_late_us` (each timed wait's return behind
    /// its deadline), each {p50, p99, p999, max, mean, count}; `stalls` (either later than
    /// 250 µs); `rt` {policy, priority} obtained; `warnings` (SCHED_FIFO refused).
    fn timing<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = self.inner.timing();
        let d = PyDict::new(py);
        d.set_item("reply_late_us", percentiles(py, &t.reply_late_us)?)?;
        d.set_item("wake_late_us", percentiles(py, &t.wake_late_us)?)?;
        d.set_item("stalls", t.stalls)?;
        let rt = PyDict::new(py);
        rt.set_item("policy", t.rt.policy)?;
        rt.set_item("priority", t.rt.priority)?;
        d.set_item("rt", rt)?;
        d.set_item("warnings", PyList::new(py, t.warnings)?)?;
        Ok(d)
    }
}

/// The bus thread's SCHED_FIFO priority unless told otherwise: the RT loop's own default
/// (`AdmittanceLoop`'s `rt_priority`), so that a loop and a mock built with defaults are equals.
pub(crate) const DEFAULT_RT_PRIORITY: i64 = ::rt::sched::DEFAULT_PRIORITY as i64;

/// The motor constants the simulated servos of `model` use: `kt` (N·m/A at the output shaft),
/// `resistance` (Ω) and `max_pwm` (the duty cap); None for a model without them. The bring-up
/// wizard turns Present Current / Load into torque with them.
#[pyfunction]
fn motor_constants<'py>(py: Python<'py>, model: &str) -> PyResult<Option<Bound<'py, PyDict>>> {
    let Some(motor) = dxlsim::motor::Motor::for_model(model, 12.0) else { return Ok(None) };
    let d = PyDict::new(py);
    d.set_item("kt", motor.kt)?;
    d.set_item("resistance", motor.resistance)?;
    d.set_item("max_pwm", dxlsim::motor::MAX_PWM)?;
    Ok(Some(d))
}

/// The Baud Rate register value of `baudrate` on a firmware protocol (1 or 2), None if it has none.
#[pyfunction]
fn baud_code(py: Python<'_>, protocol: u8, baudrate: u32) -> PyResult<Option<i64>> {
    let protocol = match protocol {
        1 => Protocol::V1,
        2 => Protocol::V2,
        p => return Err(config_error(py, format!("Dynamixel protocol is 1 or 2, not {p}"))),
    };
    Ok(dxlsim::setup::baud_code(protocol, baudrate))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(motor_constants, m)?)?;
    m.add_function(wrap_pyfunction!(baud_code, m)?)?;
    m.add_class::<PyMockBus>()
}
