//! Python bindings of the `rt` crate: `AdmittanceLoop` and its `ForceSink` (Contract 5).
//!
//! The configuration dict is read here, key by key, into `rt::LoopConfig`; an unknown key
//! or a bad value is an `admittance.errors.ConfigError` naming the key, a missing or silent bus
//! at `start()` an `admittance.errors.DeviceError`. `start()` and `stop()` block (bus reads,
//! thread join) and release the GIL while they do; everything else is O(1) or proportional to
//! the telemetry drained. The RT thread itself never touches Python.
use dxl::Protocol;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};
use plant::servo::{ServoModel, SERVO_PARAM_DEFAULTS, SERVO_PARAM_NAMES};
use rt::bus::ReadChoice;
use rt::fault::{FaultKind, Faults, LoopMode};
use rt::recovery::{FaultPolicy, OnServoError, OnTorqueOff, StopCause, UNSAFE_HARDWARE_ERRORS};
use rt::histogram::Percentiles;
use rt::params::{joint_value, LoopParams};
use rt::sched::{Policy, RtRequest};
use rt::sensor::ForceSample;
use rt::telemetry::{Record, RECORD_FIELDS};
use rt::{ForceSink, JointConfig, LoopConfig, LoopHandle, ParamValue, StartError, StopPolicy, TriggerMode};
use crate::dict_fields::{first_unknown_key, opt};
use crate::dxlsim::PyMockBus;
use crate::errors::{config_error, device_error};

const LOOP_KEYS: [&str; 23] = [
    "port",
    "baudrate",
    "protocol",
    "bus_read",
    "rate_hz",
    "rt_policy",
    "rt_priority",
    "lock_memory",
    "cpu",
    "joints",
    "sync_read_divisor",
    "stale_timeout_ms",
    "deadband",
    "lowpass_hz",
    "ramp_time_s",
    "bias",
    "force_capacity",
    "telemetry_capacity",
    "start_timeout_ms",
    "torque_on_start",
    "trigger",
    "phase_lock",
    "faults",
];

const FAULT_KEYS: [&str; 8] = [
    "servo_error",
    "torque_off",
    "bus_lost_timeout_s",
    "servo_silent_ms",
    "max_recoveries",
    "recovery_window_s",
    "check_period_ms",
    "horn_speed_max",
];

const JOINT_KEYS: [&str; 23] = [
    "id",
    "model",
    "goal_address",
    "goal_size",
    "present_address",
    "present_size",
    "torque_enable_address",
    "zero_tick",
    "direction",
    "ticks_per_rev",
    "tick_min",
    "tick_max",
    "virtual_inertia",
    "virtual_damping",
    "virtual_coulomb",
    "axis",
    "lever_arm",
    "limits",
    "servo",
    "servo_compensation",
    "passivity_guard",
    "passivity_margin",
    "passivity_damping_max",
];

const LIMIT_KEYS: [&str; 4] = ["position_min", "position_max", "velocity_max", "acceleration_max"];
const AXES: [&str; 6] = ["x", "y", "z", "tx", "ty", "tz"];

fn check_keys(d: &Bound<'_, PyDict>, known: &[&str], where_: &str) -> PyResult<()> {
    match first_unknown_key(d, known, where_)? {
        Some(key) => Err(config_error(d.py(), format!("{where_}: unknown key {key:?} (known: {})", known.join(", ")))),
        None => Ok(()),
    }
}

fn set<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, key: &str, where_: &str, slot: &mut T) -> PyResult<()> {
    if let Some(v) = opt(d, key, where_)? {
        *slot = v;
    }
    Ok(())
}

fn axis_of(obj: &Bound<'_, PyAny>, where_: &str) -> PyResult<usize> {
    if let Ok(k) = obj.extract::<usize>() {
        return Ok(k);
    }
    let name: String = obj.extract().unwrap_or_default();
    AXES.iter().position(|a| *a == name.to_lowercase()).ok_or_else(|| {
        config_error(obj.py(), format!("{where_}.axis: {obj} is not one of {} or 0..=5", AXES.join(", ")))
    })
}

fn joint_config(d: &Bound<'_, PyDict>, k: usize, protocol: Protocol) -> PyResult<JointConfig> {
    let py = d.py();
    let where_ = format!("joints[{k}]");
    check_keys(d, &JOINT_KEYS, &where_)?;
    let id: u8 = opt(d, "id", &where_)?.ok_or_else(|| config_error(py, format!("{where_}: \"id\" is required")))?;
    let mut j = JointConfig::new(id, protocol);
    set(d, "model", &where_, &mut j.model)?;
    let r = &mut j.registers;
    set(d, "goal_address", &where_, &mut r.goal_address)?;
    set(d, "goal_size", &where_, &mut r.goal_size)?;
    set(d, "present_address", &where_, &mut r.present_address)?;
    set(d, "present_size", &where_, &mut r.present_size)?;
    set(d, "torque_enable_address", &where_, &mut r.torque_enable_address)?;
    let t = &mut j.ticks;
    set(d, "zero_tick", &where_, &mut t.zero_tick)?;
    set(d, "direction", &where_, &mut t.direction)?;
    set(d, "ticks_per_rev", &where_, &mut t.ticks_per_rev)?;
    set(d, "tick_min", &where_, &mut t.tick_min)?;
    set(d, "tick_max", &where_, &mut t.tick_max)?;
    // The default position limits follow the (possibly configured) tick range.
    (j.limits.position_min, j.limits.position_max) = j.ticks.theta_range();
    set(d, "virtual_inertia", &where_, &mut j.gains.inertia)?;
    set(d, "virtual_damping", &where_, &mut j.gains.damping)?;
    set(d, "virtual_coulomb", &where_, &mut j.gains.coulomb)?;
    set(d, "lever_arm", &where_, &mut j.gains.lever_arm)?;
    if let Some(axis) = d.get_item("axis")?.filter(|a| !a.is_none()) {
        j.axis = axis_of(&axis, &where_)?;
    }
    if let Some(limits) = opt::<Bound<'_, PyDict>>(d, "limits", &where_)? {
        let where_ = format!("{where_}.limits");
        check_keys(&limits, &LIMIT_KEYS, &where_)?;
        let l = &mut j.limits;
        set(&limits, "position_min", &where_, &mut l.position_min)?;
        set(&limits, "position_max", &where_, &mut l.position_max)?;
        set(&limits, "velocity_max", &where_, &mut l.velocity_max)?;
        set(&limits, "acceleration_max", &where_, &mut l.acceleration_max)?;
    }
    if let Some(servo) = opt::<Bound<'_, PyDict>>(d, "servo", &where_)? {
        j.servo = Some(servo_model(&servo, &format!("{where_}.servo"))?);
    }
    // On by default when the joint has a servo model.
    j.compensation = if j.servo.is_some() { 1.0 } else { 0.0 };
    set(d, "servo_compensation", &where_, &mut j.compensation)?;
    set(d, "passivity_guard", &where_, &mut j.passivity.guard)?;
    set(d, "passivity_margin", &where_, &mut j.passivity.margin)?;
    set(d, "passivity_damping_max", &where_, &mut j.passivity.damping_max)?;
    Ok(j)
}

/// A `[servo]` table: `SERVO_PARAM_NAMES`, numbers; the ones with a default may be left out.
fn servo_model(d: &Bound<'_, PyDict>, where_: &str) -> PyResult<ServoModel> {
    check_keys(d, &SERVO_PARAM_NAMES, where_)?;
    let mut values = [0.0; SERVO_PARAM_NAMES.len()];
    for ((value, name), default) in values.iter_mut().zip(SERVO_PARAM_NAMES).zip(SERVO_PARAM_DEFAULTS) {
        *value = opt(d, name, where_)?
            .or(default)
            .ok_or_else(|| config_error(d.py(), format!("{where_}: \"{name}\" is required")))?;
    }
    ServoModel::from_slice(&values).map_err(|e| config_error(d.py(), format!("{where_}: {e}")))
}

fn rt_request(d: &Bound<'_, PyDict>) -> PyResult<RtRequest> {
    let py = d.py();
    let mut rt = RtRequest::default();
    set(d, "rt_priority", "config", &mut rt.priority)?;
    set(d, "lock_memory", "config", &mut rt.lock_memory)?;
    rt.cpu = opt(d, "cpu", "config")?;
    let policy: String = opt(d, "rt_policy", "config")?.unwrap_or_else(|| "fifo".into());
    rt.policy = match policy.to_lowercase().as_str() {
        "fifo" | "sched_fifo" if rt.priority > 0 => Policy::Fifo,
        "fifo" | "sched_fifo" | "other" | "sched_other" => Policy::Other,
        _ => return Err(config_error(py, format!("config.rt_policy: {policy:?} is not \"fifo\" or \"other\""))),
    };
    Ok(rt)
}

/// A duration in seconds (`scale` 1) or ms (`scale` 1e-3) as nanoseconds: finite and > 0.
fn duration_ns(d: &Bound<'_, PyDict>, key: &str, scale: f64, slot: &mut u64) -> PyResult<()> {
    let Some(value) = opt::<f64>(d, key, "config.faults")? else { return Ok(()) };
    if !(value.is_finite() && value > 0.0) {
        return Err(config_error(d.py(), format!("config.faults.{key}: must be a positive number, got {value}")));
    }
    *slot = (value * scale * 1e9).min(u64::MAX as f64) as u64;
    Ok(())
}

/// The `faults` table's choices by name: the parser and the exported defaults share them.
const SERVO_ERROR_CHOICES: [(&str, OnServoError); 2] = [("reboot", OnServoError::Reboot), ("stop", OnServoError::Stop)];
const TORQUE_OFF_CHOICES: [(&str, OnTorqueOff); 2] = [("reenable", OnTorqueOff::Reenable), ("stop", OnTorqueOff::Stop)];

/// The name of `value` in `choices` ("" if absent, which the tables above rule out).
fn choice_name<T: PartialEq>(choices: &[(&'static str, T)], value: &T) -> &'static str {
    choices.iter().find(|(_, v)| v == value).map_or("", |(name, _)| name)
}

/// `d[key]`, one of `choices` by name, into `slot` when present.
fn set_choice<T: Copy>(d: &Bound<'_, PyDict>, key: &str, choices: &[(&str, T)], slot: &mut T) -> PyResult<()> {
    let Some(name) = opt::<String>(d, key, "config.faults")? else { return Ok(()) };
    match choices.iter().find(|(n, _)| *n == name) {
        Some((_, value)) => *slot = *value,
        None => {
            let known: Vec<String> = choices.iter().map(|(n, _)| format!("\"{n}\"")).collect();
            return Err(config_error(d.py(), format!("config.faults.{key}: {name:?} is not {}", known.join(" or "))));
        }
    }
    Ok(())
}

/// The `faults` table: the servo and bus fault policy (docs/faults.md).
fn fault_policy(d: &Bound<'_, PyDict>) -> PyResult<FaultPolicy> {
    check_keys(d, &FAULT_KEYS, "config.faults")?;
    let mut p = FaultPolicy::default();
    set_choice(d, "servo_error", &SERVO_ERROR_CHOICES, &mut p.servo_error)?;
    set_choice(d, "torque_off", &TORQUE_OFF_CHOICES, &mut p.torque_off)?;
    duration_ns(d, "bus_lost_timeout_s", 1.0, &mut p.lost_timeout_ns)?;
    duration_ns(d, "servo_silent_ms", 1e-3, &mut p.silent_after_ns)?;
    duration_ns(d, "recovery_window_s", 1.0, &mut p.recovery_window_ns)?;
    duration_ns(d, "check_period_ms", 1e-3, &mut p.check_period_ns)?;
    set(d, "max_recoveries", "config.faults", &mut p.max_recoveries)?;
    set(d, "horn_speed_max", "config.faults", &mut p.horn_speed_max)?;
    Ok(p)
}

/// Whether `mode` moves its grid onto the sensor (only `sample` can).
fn phase_lock_of(mode: &TriggerMode) -> bool {
    matches!(mode, TriggerMode::Sample { phase_lock: true })
}

/// `trigger` ("sample" or "schedule") and `phase_lock` (sample only).
fn trigger_mode(d: &Bound<'_, PyDict>) -> PyResult<TriggerMode> {
    let py = d.py();
    let default = TriggerMode::default();
    let phase_lock: bool = opt(d, "phase_lock", "config")?.unwrap_or(phase_lock_of(&default));
    let name: String = opt(d, "trigger", "config")?.unwrap_or_else(|| default.name().into());
    match name.as_str() {
        "sample" => Ok(TriggerMode::Sample { phase_lock }),
        "schedule" => Ok(TriggerMode::Schedule),
        _ => Err(config_error(py, format!("config.trigger: {name:?} is not \"sample\" or \"schedule\""))),
    }
}

/// The configuration as a dict: the daemon's typed `admittance.loop_config.LoopConfig` (a frozen
/// msgspec Struct, converted here by `msgspec.to_builtins`, which leaves its unset fields out so
/// they take the loop's defaults), or a dict of the same keys (the benches and tests).
pub(crate) fn config_dict<'py>(config: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyDict>> {
    if let Ok(d) = config.cast::<PyDict>() {
        return Ok(d.clone());
    }
    let py = config.py();
    let builtins = py.import("msgspec")?.call_method1("to_builtins", (config,))?;
    builtins.cast_into::<PyDict>().map_err(|_| {
        let kind = config.get_type().name().map(|n| n.to_string()).unwrap_or_default();
        config_error(py, format!("config: expected a LoopConfig or a dict, got {kind}"))
    })
}

pub(crate) fn loop_config(d: &Bound<'_, PyDict>) -> PyResult<LoopConfig> {
    let py = d.py();
    check_keys(d, &LOOP_KEYS, "config")?;
    let port = opt(d, "port", "config")?;
    let port = port.ok_or_else(|| config_error(py, "config: \"port\" (the Dynamixel bus device) is required"))?;
    let mut c = LoopConfig { port, ..Default::default() };
    set(d, "baudrate", "config", &mut c.baudrate)?;
    let protocol: u8 = opt(d, "protocol", "config")?.unwrap_or(c.protocol.number());
    c.protocol = Protocol::from_number(protocol)
        .ok_or_else(|| config_error(py, format!("config.protocol: must be 1 or 2, got {protocol}")))?;
    if let Some(read) = opt::<String>(d, "bus_read", "config")? {
        c.bus_read = ReadChoice::parse(&read).ok_or_else(|| {
            config_error(py, format!("config.bus_read: must be one of {}, got {read:?}", ReadChoice::NAMES.join(", ")))
        })?;
    }
    set(d, "rate_hz", "config", &mut c.rate_hz)?;
    c.rt = rt_request(d)?;
    c.trigger = trigger_mode(d)?;
    set(d, "sync_read_divisor", "config", &mut c.sync_read_divisor)?;
    set(d, "stale_timeout_ms", "config", &mut c.sensor.stale_timeout_ms)?;
    set(d, "deadband", "config", &mut c.sensor.deadband)?;
    set(d, "lowpass_hz", "config", &mut c.sensor.lowpass_hz)?;
    set(d, "ramp_time_s", "config", &mut c.ramp_time_s)?;
    set(d, "bias", "config", &mut c.bias)?;
    set(d, "force_capacity", "config", &mut c.force_capacity)?;
    set(d, "telemetry_capacity", "config", &mut c.telemetry_capacity)?;
    set(d, "start_timeout_ms", "config", &mut c.start_timeout_ms)?;
    set(d, "torque_on_start", "config", &mut c.torque_on_start)?;
    if let Some(faults) = opt::<Bound<'_, PyDict>>(d, "faults", "config")? {
        c.faults = fault_policy(&faults)?;
    }
    let joints: Vec<Bound<'_, PyDict>> = opt(d, "joints", "config")?.unwrap_or_default();
    c.joints = joints.iter().enumerate().map(|(k, j)| joint_config(j, k, c.protocol)).collect::<PyResult<_>>()?;
    c.validate().map_err(|e| config_error(py, e))?;
    Ok(c)
}

pub(crate) fn percentiles<'py>(py: Python<'py>, p: &Percentiles) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("p50", p.p50)?;
    d.set_item("p99", p.p99)?;
    d.set_item("p999", p.p999)?;
    d.set_item("max", p.max)?;
    d.set_item("mean", p.mean)?;
    d.set_item("count", p.count)?;
    Ok(d)
}

fn params_dict<'py>(py: Python<'py>, p: &LoopParams, ids: &[u8]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (joint, id) in p.joints.iter().zip(ids) {
        for key in rt::params::known_names() {
            if let Some(v) = joint_value(joint, key) {
                d.set_item(format!("{id}.{key}"), v)?;
            }
        }
    }
    d.set_item("deadband", p.sensor.deadband)?;
    d.set_item("lowpass_hz", p.sensor.lowpass_hz)?;
    d.set_item("stale_timeout_ms", p.sensor.stale_timeout_ms)?;
    d.set_item("ramp_time_s", p.ramp_time_s)?;
    d.set_item("bias", p.bias.to_vec())?;
    Ok(d)
}

/// At most `n` characters of `text`, marked when cut: a reason never echoes a megabyte of input.
fn truncated(text: &str, n: usize) -> String {
    match text.char_indices().nth(n) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text.to_string(),
    }
}

/// A set_params value: a number, or a list of 6 numbers (bias). A Python int too large for a
/// float (OverflowError) is refused here like any other bad value.
fn param_value(name: &str, v: &Bound<'_, PyAny>) -> Result<ParamValue, String> {
    if let Ok(x) = v.extract::<f64>() {
        return Ok(ParamValue::Scalar(x));
    }
    v.extract::<[f64; 6]>().map(ParamValue::Vector).map_err(|_| {
        let shown = v.str().map(|s| truncated(&s.to_string_lossy(), 40)).unwrap_or_default();
        format!("'{}' must be a number (or, for bias, 6 numbers), got {shown}", truncated(name, 40))
    })
}

fn start_error(py: Python<'_>, e: StartError) -> PyErr {
    match e {
        StartError::AlreadyStarted => PyRuntimeError::new_err(e.to_string()),
        other => device_error(py, other.to_string()),
    }
}

/// The sink force readers push samples into (`push(t_ns, forces) -> bool`).
#[pyclass(name = "ForceSink", module = "admittance._rtcore", frozen)]
pub struct PyForceSink {
    pub(crate) inner: ForceSink,
}

#[pymethods]
impl PyForceSink {
    /// `t_ns` = time.monotonic_ns() at arrival; `forces` = up to 6 numbers [fx, fy, fz, tx, ty, tz]
    /// (missing trailing components are 0; all finite). False when the ring is full and the
    /// sample dropped; ValueError for a NaN or a stamp that is not `time.monotonic_ns()`.
    fn push(&self, t_ns: u64, forces: Vec<f64>) -> PyResult<bool> {
        if forces.is_empty() || forces.len() > 6 {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "forces must hold 1 to 6 numbers [fx, fy, fz, tx, ty, tz], got {}",
                forces.len()
            )));
        }
        let mut sample = ForceSample { t_ns, forces: [0.0; 6] };
        sample.forces[..forces.len()].copy_from_slice(&forces);
        ForceSink::check(&sample).map_err(pyo3::exceptions::PyValueError::new_err)?;
        Ok(self.inner.push(sample))
    }
}

/// The real-time admittance loop (Contract 5; keys in docs/realtime.md).
#[pyclass(name = "AdmittanceLoop", module = "admittance._rtcore", frozen)]
pub struct PyAdmittanceLoop {
    inner: LoopHandle,
}

#[pymethods]
impl PyAdmittanceLoop {
    #[new]
    fn new(config: &Bound<'_, PyAny>) -> PyResult<Self> {
        let py = config.py();
        let inner = LoopHandle::new(loop_config(&config_dict(config)?)?).map_err(|e| config_error(py, e))?;
        Ok(PyAdmittanceLoop { inner })
    }

    /// Opens the bus, reads every joint's present position (bumpless start), spawns the RT
    /// thread and returns once it runs. With `simulated_bus` (a `MockBus` in this process: the
    /// daemon's embedded bench) the loop talks to its servos through an in-process link, not
    /// through the configured port (dxlsim's `direct` module says why).
    #[pyo3(signature = (simulated_bus=None))]
    fn start(&self, py: Python<'_>, simulated_bus: Option<PyRef<'_, PyMockBus>>) -> PyResult<()> {
        match simulated_bus.map(|bus| bus.direct_link()) {
            Some(link) => py.detach(|| self.inner.start_with(Box::new(link))),
            None => py.detach(|| self.inner.start()),
        }
        .map_err(|e| start_error(py, e))
    }

    /// Stops the loop: "hold" keeps the last goal, "torque_off" disables torque on every joint.
    #[pyo3(signature = (torque_policy="hold"))]
    fn stop(&self, py: Python<'_>, torque_policy: &str) -> PyResult<()> {
        let policy = match torque_policy {
            "hold" => StopPolicy::Hold,
            "torque_off" => StopPolicy::TorqueOff,
            other => return Err(config_error(py, format!("torque_policy must be \"hold\" or \"torque_off\", got {other:?}"))),
        };
        py.detach(|| self.inner.stop(policy)).map_err(|e| device_error(py, e))
    }

    fn force_sink(&self) -> PyForceSink {
        PyForceSink { inner: self.inner.force_sink() }
    }

    /// Validates every change together; applies all of them (ramped) or none.
    fn set_params(&self, changes: &Bound<'_, PyDict>) -> PyResult<(bool, String)> {
        let mut parsed = Vec::with_capacity(changes.len());
        for (name, value) in changes.iter() {
            let Ok(name) = name.extract::<String>() else {
                let shown = name.str().map(|s| truncated(&s.to_string_lossy(), 40)).unwrap_or_default();
                return Ok((false, format!("parameter names must be strings, got {shown}")));
            };
            match param_value(&name, &value) {
                Ok(v) => parsed.push((name, v)),
                Err(reason) => return Ok((false, reason)),
            }
        }
        Ok(match self.inner.set_params(&parsed) {
            Ok(()) => (true, String::new()),
            Err(reason) => (false, reason),
        })
    }

    /// The accepted parameters, flat: "<id>.<name>" per joint, loop-wide names bare.
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        params_dict(py, &self.inner.params(), self.inner.ids())
    }

    /// Averages the next `samples` force samples into the bias.
    #[pyo3(signature = (samples=100))]
    fn tare(&self, samples: u32) {
        self.inner.tare(samples);
    }

    /// Every queued telemetry record, as a numpy structured array (one row per joint per cycle).
    fn drain_telemetry<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let mut records = Vec::new();
        self.inner.drain_telemetry(&mut records);
        records_array(py, &records)
    }

    /// The numpy dtype of `drain_telemetry`'s rows.
    #[staticmethod]
    fn telemetry_dtype(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
        telemetry_dtype(py)
    }

    /// The --stats-json object of the daemon contract (plus work_us, telemetry_drops, sync_reads,
    /// reads_deferred, bus_error_kinds: bus_errors by where they came from, faults: events per
    /// fault kind, and mode: "running", "holding" or "faulted", passivity: each joint's passivity
    /// guard).
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.inner.stats();
        let d = PyDict::new(py);
        d.set_item("cycles", s.cycles)?;
        d.set_item("overruns", s.overruns)?;
        d.set_item("rate_hz", s.rate_hz)?;
        d.set_item("period_us", percentiles(py, &s.period_us)?)?;
        d.set_item("latency_us", percentiles(py, &s.latency_us)?)?;
        d.set_item("work_us", percentiles(py, &s.work_us)?)?;
        d.set_item("bus_errors", s.bus_errors)?;
        let kinds = PyDict::new(py);
        for (name, errors) in &s.bus_error_kinds {
            kinds.set_item(*name, *errors)?;
        }
        d.set_item("bus_error_kinds", kinds)?;
        d.set_item("sensor_samples", s.sensor_samples)?;
        d.set_item("sensor_stale_events", s.sensor_stale_events)?;
        d.set_item("telemetry_drops", s.telemetry_drops)?;
        d.set_item("compensation_fallbacks", s.compensation_fallbacks)?;
        d.set_item("sync_reads", s.sync_reads)?;
        d.set_item("reads_deferred", s.reads_deferred)?;
        let faults = PyDict::new(py);
        for (name, events) in &s.faults {
            faults.set_item(*name, *events)?;
        }
        d.set_item("faults", faults)?;
        d.set_item("mode", s.mode.name())?;
        let rt = PyDict::new(py);
        rt.set_item("policy", s.rt.policy)?;
        rt.set_item("priority", s.rt.priority)?;
        rt.set_item("memory_locked", s.rt.memory_locked)?;
        rt.set_item("cpu", s.rt.cpu)?;
        d.set_item("rt", rt)?;
        d.set_item("servos", self.servos_list(py)?)?;
        d.set_item("passivity", self.passivity_list(py)?)?;
        d.set_item("bus", self.link_dict(py)?)?;
        d.set_item("trigger", trigger_dict(py, &self.inner)?)?;
        Ok(d)
    }

    /// The loop's request to be stopped, None while it has none: `{"cause": name, "joint": id
    /// or None, "hardware_error": bits}` (docs/faults.md maps each cause to an exit status).
    fn stop_request<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(req) = self.inner.stop_request() else { return Ok(None) };
        let d = PyDict::new(py);
        d.set_item("cause", req.cause.name())?;
        d.set_item("joint", req.joint.and_then(|k| self.inner.ids().get(k).copied()))?;
        d.set_item("hardware_error", req.hardware_error)?;
        Ok(Some(d))
    }

    /// Raises the sensor's faults (names of `FAULT_KINDS`: "sensor_lost", "sensor_saturated")
    /// for the cycles from now on, so the records mark them; an empty list clears them.
    fn set_sensor_faults(&self, names: Vec<String>) -> PyResult<()> {
        let mut faults = Faults::NONE;
        for name in &names {
            let kind = FaultKind::ALL.iter().find(|k| k.name() == name && FaultKind::EXTERNAL.contains(**k));
            let kind = kind.ok_or_else(|| pyo3::exceptions::PyValueError::new_err(format!("{name:?} is not a sensor fault kind")))?;
            faults.insert(*kind);
        }
        self.inner.set_external_faults(faults);
        Ok(())
    }

    /// What the loop could not get (SCHED_FIFO, mlockall, affinity, port setup), once each.
    fn warnings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        PyList::new(py, self.inner.warnings())
    }

    /// Cycles so far; a watchdog follows it.
    fn heartbeat(&self) -> u64 {
        self.inner.heartbeat()
    }

    fn running(&self) -> bool {
        self.inner.running()
    }

    /// The joints' servo IDs, in configuration order.
    #[getter]
    fn ids(&self) -> Vec<u8> {
        self.inner.ids().to_vec()
    }

    #[getter]
    fn rate_hz(&self) -> f64 {
        self.inner.config().rate_hz
    }
}

impl PyAdmittanceLoop {
    /// Per joint: its servo's recovery (`phase`), hardware error (now, and of the last one
    /// counted), silence and counts.
    fn servos_list<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for (id, s) in self.inner.ids().iter().zip(self.inner.servos()) {
            let (c, d) = (s.counts, PyDict::new(py));
            d.set_item("id", id)?;
            d.set_item("phase", s.phase)?;
            d.set_item("hardware_error", s.hardware_error)?;
            d.set_item("last_error", s.last_error)?;
            d.set_item("silent", s.silent)?;
            for (name, n) in [
                ("errors", c.errors),
                ("tolerated", c.tolerated),
                ("torque_offs", c.torque_offs),
                ("reboots", c.reboots),
                ("reenables", c.reenables),
                ("recoveries", c.recoveries),
                ("silences", c.silences),
            ] {
                d.set_item(name, n)?;
            }
            list.append(d)?;
        }
        Ok(list)
    }

    /// Per joint: its passivity guard's energy balance (J), the port's energy and the model's
    /// dissipation since the start (J), the damping it adds now (N·m·s/rad) and its episodes.
    fn passivity_list<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for (id, g) in self.inner.ids().iter().zip(self.inner.passivity()) {
            let d = PyDict::new(py);
            d.set_item("id", id)?;
            d.set_item("energy", g.balance)?;
            d.set_item("port_energy", g.port)?;
            d.set_item("model_dissipated", g.model_dissipated)?;
            d.set_item("damping", g.damping)?;
            d.set_item("episodes", g.episodes)?;
            list.append(d)?;
        }
        Ok(list)
    }

    /// The bus's port: its kind of link, lost (for how long), losses, reconnects, reopen attempts and failures.
    fn link_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let l = self.inner.link();
        let d = PyDict::new(py);
        d.set_item("state", if l.lost_for_ns.is_some() { "lost" } else { "up" })?;
        d.set_item("link", l.kind)?;
        d.set_item("read", (!l.read.is_empty()).then_some(l.read))?;
        d.set_item("lost_for_s", l.lost_for_ns.map(|ns| ns as f64 * 1e-9))?;
        d.set_item("losses", l.losses)?;
        d.set_item("loss_errno", l.loss_errno)?;
        d.set_item("reconnects", l.reconnects)?;
        d.set_item("reopen_attempts", l.reopen_attempts)?;
        d.set_item("reopen_failures", l.reopen_failures)?;
        d.set_item("last_error", (!l.last_error.is_empty()).then_some(l.last_error))?;
        Ok(d)
    }
}

/// How the cycles started: counts per cause, the arrival period seen, the phase lock's error.
fn trigger_dict<'py>(py: Python<'py>, inner: &LoopHandle) -> PyResult<Bound<'py, PyDict>> {
    let (mode, s) = inner.trigger_stats();
    let d = PyDict::new(py);
    d.set_item("mode", mode.name())?;
    d.set_item("phase_lock", phase_lock_of(&mode))?;
    let starts = PyDict::new(py);
    starts.set_item("schedule", s.schedule)?;
    starts.set_item("open", s.open)?;
    starts.set_item("arrival", s.arrival)?;
    starts.set_item("fallback", s.fallback)?;
    d.set_item("starts", starts)?;
    d.set_item("sensor_interval_us", s.sensor_interval_us)?;
    d.set_item("sensor_jitter_us", s.sensor_jitter_us)?;
    d.set_item("phase_error_us", s.phase_error_us)?;
    Ok(d)
}

/// Telemetry records as a numpy structured array of `telemetry_dtype` (a copy it owns).
pub(crate) fn records_array<'py>(py: Python<'py>, records: &[Record]) -> PyResult<Bound<'py, PyAny>> {
    let mut bytes = Vec::with_capacity(records.len() * 8 * RECORD_FIELDS.len());
    records.iter().for_each(|r| r.write_le(&mut bytes));
    let numpy = py.import("numpy")?;
    let array = numpy.call_method1("frombuffer", (PyBytes::new(py, &bytes), telemetry_dtype(py)?))?;
    array.call_method0("copy")
}

pub(crate) fn telemetry_dtype(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    let fields: Vec<(&str, &str)> = RECORD_FIELDS.to_vec();
    py.import("numpy")?.call_method1("dtype", (fields,))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyAdmittanceLoop>()?;
    m.add_class::<PyForceSink>()?;
    // The telemetry's `mode` codes and `fault` bits, by name: LOOP_MODES[mode], FAULT_KINDS[bit].
    m.add("LOOP_MODES", LoopMode::ALL.iter().map(|mode| mode.name()).collect::<Vec<_>>())?;
    m.add("FAULT_KINDS", FaultKind::ALL.iter().map(|kind| kind.name()).collect::<Vec<_>>())?;
    // Model steps a late cycle catches up at most; a longer stall loses its time (recording.py).
    m.add("MAX_CATCH_UP_STEPS", rt::cycle::MAX_CATCH_UP_STEPS)?;
    // Model steps a cycle takes at most while catching up (recording.py weighs its torque so).
    m.add("CATCH_UP_STEPS_PER_CYCLE", rt::cycle::CATCH_UP_STEPS_PER_CYCLE)?;
    m.add("MAX_JOINT_ID", rt::params::MAX_JOINT_ID)?;
    m.add_function(wrap_pyfunction!(split_param_name, m)?)?;
    m.add("LOOP_DEFAULTS", loop_defaults(m.py())?)?;
    m.add("LOOP_BOUNDS", loop_bounds(m.py())?)?;
    // Why the loop may ask to be stopped (`stop_request()["cause"]`), and the hardware errors
    // it never reboots for (the daemon's start-up check applies the same rule).
    m.add("STOP_CAUSES", StopCause::ALL.iter().map(|c| c.name()).collect::<Vec<_>>())?;
    m.add("UNSAFE_HARDWARE_ERRORS", UNSAFE_HARDWARE_ERRORS)?;
    Ok(())
}


/// `"3.limits.position_max"` → (3, "position_max"); a loop-wide or all-joints name has no id
/// (None). ValueError when the id is not 0..=MAX_JOINT_ID. The one parser of the grammar.
#[pyfunction]
fn split_param_name(name: &str) -> PyResult<(Option<u8>, String)> {
    rt::params::split_name(name).map(|(id, key)| (id, key.to_string())).map_err(PyValueError::new_err)
}

/// The (low, high) bounds of the fault policy's keys whose limits the loop itself sets (a fixed
/// ring of recoveries, a glitch check that means something), by the daemon's key names: the
/// daemon's configuration takes its bounds for them from here.
fn loop_bounds(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("max_recoveries", (0, rt::recovery::MAX_RECOVERIES_LIMIT))?;
    d.set_item("horn_speed_max", rt::recovery::HORN_SPEED_MAX_RANGE)?;
    Ok(d)
}

/// The loop's own defaults (rt::config, rt::recovery, rt::passivity), by the daemon's key names
/// and units: the daemon's configuration reads its defaults for the same keys from here, so the
/// two cannot differ (tests/test_rtcore_stub.py holds every shared key to it).
fn loop_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let c = LoopConfig::default();
    let j = JointConfig::new(1, c.protocol);
    let f = FaultPolicy::default();
    let d = PyDict::new(py);
    d.set_item("baudrate", c.baudrate)?;
    d.set_item("protocol", c.protocol.number())?;
    d.set_item("rate_hz", c.rate_hz)?;
    d.set_item("lock_memory", c.rt.lock_memory)?;
    d.set_item("trigger", c.trigger.name())?;
    d.set_item("phase_lock", phase_lock_of(&c.trigger))?;
    d.set_item("sync_read_divisor", c.sync_read_divisor)?;
    d.set_item("ramp_time_s", c.ramp_time_s)?;
    d.set_item("stale_timeout_ms", c.sensor.stale_timeout_ms)?;
    d.set_item("deadband", c.sensor.deadband)?;
    d.set_item("lowpass_hz", c.sensor.lowpass_hz)?;
    d.set_item("bias", c.bias.to_vec())?;
    d.set_item("axis", AXES[j.axis.min(AXES.len() - 1)])?;
    d.set_item("zero_tick", j.ticks.zero_tick)?;
    d.set_item("direction", j.ticks.direction)?;
    d.set_item("velocity_max", j.limits.velocity_max)?;
    d.set_item("acceleration_max", j.limits.acceleration_max)?;
    d.set_item("passivity_guard", j.passivity.guard)?;
    d.set_item("passivity_margin", j.passivity.margin)?;
    d.set_item("passivity_damping_max", j.passivity.damping_max)?;
    d.set_item("servo_error", choice_name(&SERVO_ERROR_CHOICES, &f.servo_error))?;
    d.set_item("torque_off", choice_name(&TORQUE_OFF_CHOICES, &f.torque_off))?;
    // The durations in the units of their keys (the loop keeps nanoseconds).
    d.set_item("bus_lost_timeout_s", f.lost_timeout_ns as f64 / 1e9)?;
    d.set_item("servo_silent_ms", f.silent_after_ns as f64 / 1e6)?;
    d.set_item("recovery_window_s", f.recovery_window_ns as f64 / 1e9)?;
    d.set_item("check_period_ms", f.check_period_ns as f64 / 1e6)?;
    d.set_item("max_recoveries", f.max_recoveries)?;
    d.set_item("horn_speed_max", f.horn_speed_max)?;
    Ok(d)
}
