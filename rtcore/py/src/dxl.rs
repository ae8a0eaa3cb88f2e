//! Python bindings of the `dxl` crate: CRC, the encoders of both protocols, a streaming
//! `Decoder`, the model table and `DxlClient` (the Rust serial port and client).
//!
//! Encoders return `bytes` and take `protocol=1|2` (default 2) so Python code and tests call
//! exactly the encoders the RT loop uses. Bad arguments raise `ValueError`; device problems
//! (missing port, timeout, servo error) raise `admittance.errors.DeviceError`, so the CLI
//! prints one line. `DxlClient` releases the GIL (`py.detach`) for every bus transaction.
use std::sync::Mutex;
use std::time::Duration;

use dxl::client::{Client, ClientError, Slot};
use dxl::models::{Access, Model, MODELS};
use dxl::protocol1::{self as p1, Expect};
use dxl::protocol2 as p2;
use dxl::serial::SerialPort;
use dxl::{AnyDecoder, BulkEntry, DecodeError, EncodeError, Kind, Packet, Protocol, ServoError};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};
use crate::errors::device_error;

fn protocol_of(n: u8) -> PyResult<Protocol> {
    Protocol::from_number(n).ok_or_else(|| PyValueError::new_err(format!("protocol must be 1 or 2, got {n}")))
}

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

fn client_error(py: Python<'_>, e: ClientError) -> PyErr {
    match e {
        ClientError::Encode(e) => value_error(e),
        ClientError::Unsupported { .. } => value_error(e),
        other => device_error(py, other.to_string()),
    }
}

fn byte(name: &str, v: u16) -> PyResult<u8> {
    u8::try_from(v).map_err(|_| PyValueError::new_err(format!("{name} {v} does not fit Protocol 1.0's one byte")))
}

/// Run an encoder on a buffer that grows to the size the encoder asks for.
fn encoded<'py>(py: Python<'py>, f: impl Fn(&mut [u8]) -> Result<usize, EncodeError>) -> PyResult<Bound<'py, PyBytes>> {
    let mut buf = vec![0u8; 1024];
    let n = match f(&mut buf) {
        Err(EncodeError::BufferTooSmall { needed, .. }) => {
            buf.resize(needed, 0);
            f(&mut buf)
        }
        r => r,
    }
    .map_err(value_error)?;
    Ok(PyBytes::new(py, &buf[..n]))
}

fn p2_only(protocol: u8, what: &str) -> PyResult<()> {
    match protocol_of(protocol)? {
        Protocol::V2 => Ok(()),
        Protocol::V1 => Err(PyValueError::new_err(format!("{what} does not exist in Protocol 1.0"))),
    }
}

/// CRC-16 of Protocol 2.0 (0x8005, MSB-first, init 0).
#[pyfunction]
fn crc16(data: &[u8]) -> u16 {
    dxl::crc16(data)
}

/// P1 checksum: !(sum of bytes) & 0xFF (pass ID..last parameter).
#[pyfunction]
fn checksum1(data: &[u8]) -> u8 {
    p1::checksum(data)
}

#[pyfunction]
#[pyo3(signature = (id, instruction, params=b"".as_slice(), protocol=2))]
fn encode_instruction<'py>(py: Python<'py>, id: u8, instruction: u8, params: &[u8], protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    match protocol_of(protocol)? {
        Protocol::V1 => encoded(py, |b| p1::encode_instruction(b, id, instruction, params)),
        Protocol::V2 => encoded(py, |b| p2::encode_instruction(b, id, instruction, params)),
    }
}

/// A status packet (what a servo sends); `error` is the raw error byte.
#[pyfunction]
#[pyo3(signature = (id, error=0, params=b"".as_slice(), protocol=2))]
fn encode_status<'py>(py: Python<'py>, id: u8, error: u8, params: &[u8], protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    match protocol_of(protocol)? {
        Protocol::V1 => encoded(py, |b| p1::encode_status(b, id, error, params)),
        Protocol::V2 => encoded(py, |b| p2::encode_status(b, id, error, params)),
    }
}

#[pyfunction]
#[pyo3(signature = (id, protocol=2))]
fn encode_ping<'py>(py: Python<'py>, id: u8, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    match protocol_of(protocol)? {
        Protocol::V1 => encoded(py, |b| p1::encode_ping(b, id)),
        Protocol::V2 => encoded(py, |b| p2::encode_ping(b, id)),
    }
}

#[pyfunction]
#[pyo3(signature = (id, address, length, protocol=2))]
fn encode_read<'py>(py: Python<'py>, id: u8, address: u16, length: u16, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    match protocol_of(protocol)? {
        Protocol::V1 => {
            let (a, l) = (byte("address", address)?, byte("length", length)?);
            encoded(py, |b| p1::encode_read(b, id, a, l))
        }
        Protocol::V2 => encoded(py, |b| p2::encode_read(b, id, address, length)),
    }
}

fn addressed<'py>(py: Python<'py>, instruction: u8, id: u8, address: u16, data: &[u8], protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    match protocol_of(protocol)? {
        Protocol::V1 => {
            let a = byte("address", address)?;
            encoded(py, |b| p1::encode_instruction_addressed(b, id, instruction, a, data))
        }
        Protocol::V2 => encoded(py, |b| p2::encode_addressed(b, id, instruction, address, data)),
    }
}

#[pyfunction]
#[pyo3(signature = (id, address, data, protocol=2))]
fn encode_write<'py>(py: Python<'py>, id: u8, address: u16, data: &[u8], protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    addressed(py, dxl::instruction::WRITE, id, address, data, protocol)
}

#[pyfunction]
#[pyo3(signature = (id, address, data, protocol=2))]
fn encode_reg_write<'py>(py: Python<'py>, id: u8, address: u16, data: &[u8], protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    addressed(py, dxl::instruction::REG_WRITE, id, address, data, protocol)
}

#[pyfunction]
#[pyo3(signature = (id, protocol=2))]
fn encode_action<'py>(py: Python<'py>, id: u8, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    match protocol_of(protocol)? {
        Protocol::V1 => encoded(py, |b| p1::encode_action(b, id)),
        Protocol::V2 => encoded(py, |b| p2::encode_action(b, id)),
    }
}

/// FACTORY_RESET; `option` (P2 only): 0xFF all, 0x01 all but ID, 0x02 all but ID and baud.
#[pyfunction]
#[pyo3(signature = (id, option=0xFF, protocol=2))]
fn encode_factory_reset<'py>(py: Python<'py>, id: u8, option: u8, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    match protocol_of(protocol)? {
        Protocol::V1 => encoded(py, |b| p1::encode_factory_reset(b, id)),
        Protocol::V2 => encoded(py, |b| p2::encode_factory_reset(b, id, option)),
    }
}

#[pyfunction]
#[pyo3(signature = (id, protocol=2))]
fn encode_reboot<'py>(py: Python<'py>, id: u8, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    p2_only(protocol, "REBOOT")?;
    encoded(py, |b| p2::encode_reboot(b, id))
}

#[pyfunction]
#[pyo3(signature = (address, length, ids, protocol=2))]
fn encode_sync_read<'py>(py: Python<'py>, address: u16, length: u16, ids: Vec<u8>, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    p2_only(protocol, "SYNC_READ")?;
    encoded(py, |b| p2::encode_sync_read(b, address, length, &ids))
}

#[pyfunction]
#[pyo3(signature = (address, length, ids, protocol=2))]
fn encode_fast_sync_read<'py>(py: Python<'py>, address: u16, length: u16, ids: Vec<u8>, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    p2_only(protocol, "FAST_SYNC_READ")?;
    encoded(py, |b| p2::encode_fast_sync_read(b, address, length, &ids))
}

/// Split `[(id, bytes), ...]` into the flat (ids, data) form of the Rust encoders.
fn flatten_records(data_len: u16, records: Vec<(u8, Vec<u8>)>) -> PyResult<(Vec<u8>, Vec<u8>)> {
    let mut ids = Vec::with_capacity(records.len());
    let mut data = Vec::with_capacity(records.len() * usize::from(data_len));
    for (id, bytes) in records {
        if bytes.len() != usize::from(data_len) {
            return Err(PyValueError::new_err(format!("record for ID {id} has {} bytes, expected {data_len}", bytes.len())));
        }
        ids.push(id);
        data.extend_from_slice(&bytes);
    }
    Ok((ids, data))
}

/// SYNC_WRITE of `data_len` bytes at `address`: `records` is `[(id, bytes), ...]`.
#[pyfunction]
#[pyo3(signature = (address, data_len, records, protocol=2))]
fn encode_sync_write<'py>(py: Python<'py>, address: u16, data_len: u16, records: Vec<(u8, Vec<u8>)>, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    let (ids, data) = flatten_records(data_len, records)?;
    match protocol_of(protocol)? {
        Protocol::V1 => {
            let (a, l) = (byte("address", address)?, byte("data_len", data_len)?);
            encoded(py, |b| p1::encode_sync_write(b, a, l, &ids, &data))
        }
        Protocol::V2 => encoded(py, |b| p2::encode_sync_write(b, address, data_len, &ids, &data)),
    }
}

fn bulk_entries(entries: &[(u8, u16, u16)]) -> Vec<BulkEntry> {
    entries.iter().map(|&(id, address, length)| BulkEntry { id, address, length }).collect()
}

/// BULK_READ: `entries` is `[(id, address, length), ...]`.
#[pyfunction]
#[pyo3(signature = (entries, protocol=2))]
fn encode_bulk_read<'py>(py: Python<'py>, entries: Vec<(u8, u16, u16)>, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    let entries = bulk_entries(&entries);
    match protocol_of(protocol)? {
        Protocol::V1 => encoded(py, |b| p1::encode_bulk_read(b, &entries)),
        Protocol::V2 => encoded(py, |b| p2::encode_bulk_read(b, &entries)),
    }
}

/// BULK_WRITE (P2): `entries` is `[(id, address, bytes), ...]`.
#[pyfunction]
#[pyo3(signature = (entries, protocol=2))]
fn encode_bulk_write<'py>(py: Python<'py>, entries: Vec<(u8, u16, Vec<u8>)>, protocol: u8) -> PyResult<Bound<'py, PyBytes>> {
    p2_only(protocol, "BULK_WRITE")?;
    let mut list = Vec::with_capacity(entries.len());
    let mut data = Vec::new();
    for (id, address, bytes) in &entries {
        let length = u16::try_from(bytes.len()).map_err(|_| PyValueError::new_err(format!("data for ID {id} is too long")))?;
        list.push(BulkEntry { id: *id, address: *address, length });
        data.extend_from_slice(bytes);
    }
    encoded(py, |b| p2::encode_bulk_write(b, &list, &data))
}

fn servo_error_fields(d: &Bound<'_, PyDict>, e: ServoError) -> PyResult<()> {
    d.set_item("error", e.raw())?;
    d.set_item("alert", e.alert())?;
    d.set_item("failed", e.is_failure())?;
    d.set_item("error_text", e.to_string())
}

fn packet_dict<'py>(py: Python<'py>, p: &Packet<'_>) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("id", p.id)?;
    match p.kind {
        Kind::Instruction(code) => {
            d.set_item("kind", "instruction")?;
            d.set_item("instruction", code)?;
        }
        Kind::Status(e) => {
            d.set_item("kind", "status")?;
            servo_error_fields(&d, e)?;
        }
    }
    d.set_item("params", PyBytes::new(py, p.params))?;
    Ok(d)
}

fn decode_error_dict<'py>(py: Python<'py>, e: &DecodeError) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("kind", "decode_error")?;
    d.set_item("message", e.to_string())?;
    match *e {
        DecodeError::Crc { id, expected, actual } => {
            d.set_item("type", "crc")?;
            d.set_item("id", id)?;
            d.set_item("expected", expected)?;
            d.set_item("actual", actual)?;
        }
        DecodeError::Checksum { id, expected, actual } => {
            d.set_item("type", "checksum")?;
            d.set_item("id", id)?;
            d.set_item("expected", expected)?;
            d.set_item("actual", actual)?;
        }
        DecodeError::Length { id, actual, minimum, maximum } => {
            d.set_item("type", "length")?;
            d.set_item("id", id)?;
            d.set_item("actual", actual)?;
            d.set_item("minimum", minimum)?;
            d.set_item("maximum", maximum)?;
        }
    }
    Ok(d)
}

/// Streaming decoder: `push(bytes)` returns the packets (and framing errors) completed so far.
#[pyclass(name = "Decoder", module = "admittance._rtcore")]
pub struct PyDecoder {
    inner: Mutex<AnyDecoder>,
}

#[pymethods]
impl PyDecoder {
    /// `expect` matters for Protocol 1.0 only, whose frames do not say their direction:
    /// "status" (a host listening to servos) or "instruction" (a servo listening to a host).
    #[new]
    #[pyo3(signature = (protocol=2, expect="status"))]
    fn new(protocol: u8, expect: &str) -> PyResult<Self> {
        let expect = match expect {
            "status" => Expect::Status,
            "instruction" => Expect::Instruction,
            other => return Err(PyValueError::new_err(format!("expect must be 'status' or 'instruction', got {other:?}"))),
        };
        Ok(PyDecoder { inner: Mutex::new(AnyDecoder::new(protocol_of(protocol)?, expect)) })
    }

    /// Feed bytes; returns a list of dicts: packets (`kind` "instruction" or "status", `id`,
    /// `instruction` or `error`/`alert`/`failed`, `params`) and framing errors (`kind`
    /// "decode_error", `type`, `expected`, `actual`, `message`).
    fn push<'py>(&self, py: Python<'py>, data: &[u8]) -> PyResult<Bound<'py, PyList>> {
        let out = PyList::empty(py);
        let mut dec = self.inner.lock().map_err(|_| PyRuntimeError::new_err("decoder lock poisoned"))?;
        let mut rest = data;
        loop {
            let n = dec.push(rest);
            rest = &rest[n..];
            while let Some(item) = dec.next() {
                match item {
                    Ok(p) => out.append(packet_dict(py, &p)?)?,
                    Err(e) => out.append(decode_error_dict(py, &e)?)?,
                }
            }
            if rest.is_empty() {
                return Ok(out);
            }
        }
    }

    #[getter]
    fn skipped_bytes(&self) -> u64 {
        self.inner.lock().map(|d| d.skipped_bytes()).unwrap_or(0)
    }

    /// CRC (P2) or checksum (P1) failures so far.
    #[getter]
    fn integrity_errors(&self) -> u64 {
        self.inner.lock().map(|d| d.integrity_errors()).unwrap_or(0)
    }
}

fn model_dict<'py>(py: Python<'py>, m: &Model) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("name", m.name)?;
    d.set_item("number", m.number)?;
    d.set_item("protocol", m.protocol.number())?;
    let items = PyList::empty(py);
    for it in m.items {
        let i = PyDict::new(py);
        i.set_item("name", it.name)?;
        i.set_item("address", it.address)?;
        i.set_item("size", it.size)?;
        i.set_item("access", if it.access == Access::RW { "RW" } else { "R" })?;
        i.set_item("eeprom", it.eeprom)?;
        i.set_item("signed", it.signed)?;
        i.set_item("default", it.default)?;
        i.set_item("min", it.min)?;
        i.set_item("max", it.max)?;
        i.set_item("unit", it.unit)?;
        i.set_item("count", it.count)?;
        i.set_item("default_step", it.default_step)?;
        i.set_item("first_number", it.first_number)?;
        items.append(i)?;
    }
    d.set_item("items", items)?;
    Ok(d)
}

/// Every model of the Rust table: `[{name, number, protocol, items: [{name, address, size,
/// access, eeprom, signed, default, min, max, unit, count, default_step, first_number}]}]`.
/// A run (`count` > 1) stands for elements `"{name} {first_number + k}"` at `address + k*size`.
#[pyfunction]
fn model_table<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
    let out = PyList::empty(py);
    for m in &MODELS {
        out.append(model_dict(py, m)?)?;
    }
    Ok(out)
}

/// A Dynamixel client over the Rust serial port.
#[pyclass(name = "DxlClient", module = "admittance._rtcore")]
pub struct PyDxlClient {
    inner: Mutex<Option<Client<SerialPort>>>,
    port_path: String,
}

impl PyDxlClient {
    /// Run `f` on the client without the GIL; map its error to a Python exception.
    fn call<R: Send>(&self, py: Python<'_>, f: impl FnOnce(&mut Client<SerialPort>) -> Result<R, ClientError> + Send) -> PyResult<R> {
        let result = py.detach(|| {
            let mut guard = self.inner.lock().map_err(|_| None)?;
            let client = guard.as_mut().ok_or(None)?;
            f(client).map_err(Some)
        });
        result.map_err(|e| match e {
            Some(e) => client_error(py, e),
            None => device_error(py, format!("client for {} is closed", self.port_path)),
        })
    }
}

fn slots_dict<'py>(py: Python<'py>, ids: &[u8], lens: &[usize], out: &[u8], slots: &[Slot]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let mut off = 0;
    for ((&id, &len), slot) in ids.iter().zip(lens).zip(slots) {
        match slot {
            Slot::Received(e) if !e.is_failure() => d.set_item(id, PyBytes::new(py, &out[off..off + len]))?,
            _ => d.set_item(id, py.None())?,
        }
        off += len;
    }
    Ok(d)
}

#[pymethods]
impl PyDxlClient {
    #[new]
    #[pyo3(signature = (port_path, baudrate=1_000_000, protocol=2, timeout_s=0.01))]
    fn new(py: Python<'_>, port_path: String, baudrate: u32, protocol: u8, timeout_s: f64) -> PyResult<Self> {
        let protocol = protocol_of(protocol)?;
        if !(timeout_s.is_finite() && timeout_s > 0.0) {
            return Err(PyValueError::new_err(format!("timeout_s must be a positive number, got {timeout_s}")));
        }
        let port = SerialPort::open(&port_path, baudrate).map_err(|e| device_error(py, e.to_string()))?;
        let client = Client::new(port, protocol, Duration::from_secs_f64(timeout_s));
        Ok(PyDxlClient { inner: Mutex::new(Some(client)), port_path })
    }

    /// What opening the port achieved: baud actually set, FTDI low-latency flag, and why not.
    fn open_report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let guard = self.inner.lock().map_err(|_| PyRuntimeError::new_err("client lock poisoned"))?;
        let client = guard.as_ref().ok_or_else(|| device_error(py, format!("client for {} is closed", self.port_path)))?;
        let r = client.transport().report();
        let d = PyDict::new(py);
        d.set_item("baud_actual", r.baud_actual)?;
        d.set_item("baud_error", r.baud_error.clone())?;
        d.set_item("low_latency", r.low_latency)?;
        d.set_item("low_latency_error", r.low_latency_error.clone())?;
        Ok(d)
    }

    /// `{"model_number": int, "firmware": int | None}`.
    fn ping<'py>(&self, py: Python<'py>, id: u8) -> PyResult<Bound<'py, PyDict>> {
        let info = self.call(py, |c| c.ping(id))?;
        let d = PyDict::new(py);
        d.set_item("model_number", info.model_number)?;
        d.set_item("firmware", info.firmware)?;
        Ok(d)
    }

    fn read<'py>(&self, py: Python<'py>, id: u8, address: u16, length: usize) -> PyResult<Bound<'py, PyBytes>> {
        let mut out = vec![0u8; length];
        self.call(py, |c| c.read(id, address, &mut out))?;
        Ok(PyBytes::new(py, &out))
    }

    /// Returns True when the servo flagged a hardware alert (None for broadcast writes).
    fn write(&self, py: Python<'_>, id: u8, address: u16, data: Vec<u8>) -> PyResult<Option<bool>> {
        Ok(self.call(py, |c| c.write(id, address, &data))?.map(ServoError::alert))
    }

    /// `records`: `[(id, bytes), ...]`, each `data_len` long. No reply.
    fn sync_write(&self, py: Python<'_>, address: u16, data_len: u16, records: Vec<(u8, Vec<u8>)>) -> PyResult<()> {
        let (ids, data) = flatten_records(data_len, records)?;
        self.call(py, |c| c.sync_write(address, data_len, &ids, &data))
    }

    /// `{id: bytes | None}` in listed order (None: no reply before the timeout, or an error).
    fn sync_read<'py>(&self, py: Python<'py>, address: u16, length: u16, ids: Vec<u8>) -> PyResult<Bound<'py, PyDict>> {
        let mut out = vec![0u8; ids.len() * usize::from(length)];
        let mut slots = vec![Slot::Missing; ids.len()];
        self.call(py, |c| c.sync_read(address, length, &ids, &mut out, &mut slots))?;
        slots_dict(py, &ids, &vec![usize::from(length); ids.len()], &out, &slots)
    }

    /// `entries`: `[(id, address, length), ...]`; returns `{id: bytes | None}`.
    fn bulk_read<'py>(&self, py: Python<'py>, entries: Vec<(u8, u16, u16)>) -> PyResult<Bound<'py, PyDict>> {
        let list = bulk_entries(&entries);
        let lens: Vec<usize> = list.iter().map(|e| usize::from(e.length)).collect();
        let mut out = vec![0u8; lens.iter().sum()];
        let mut slots = vec![Slot::Missing; list.len()];
        self.call(py, |c| c.bulk_read(&list, &mut out, &mut slots))?;
        let ids: Vec<u8> = list.iter().map(|e| e.id).collect();
        slots_dict(py, &ids, &lens, &out, &slots)
    }

    fn reboot(&self, py: Python<'_>, id: u8) -> PyResult<()> {
        self.call(py, |c| c.reboot(id))
    }

    /// Close the port; later calls raise DeviceError.
    fn close(&self) {
        if let Ok(mut guard) = self.inner.lock() {
            guard.take();
        }
    }

    #[getter]
    fn port_path(&self) -> &str {
        &self.port_path
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(crc16, m)?)?;
    m.add_function(wrap_pyfunction!(checksum1, m)?)?;
    m.add_function(wrap_pyfunction!(encode_instruction, m)?)?;
    m.add_function(wrap_pyfunction!(encode_status, m)?)?;
    m.add_function(wrap_pyfunction!(encode_ping, m)?)?;
    m.add_function(wrap_pyfunction!(encode_read, m)?)?;
    m.add_function(wrap_pyfunction!(encode_write, m)?)?;
    m.add_function(wrap_pyfunction!(encode_reg_write, m)?)?;
    m.add_function(wrap_pyfunction!(encode_action, m)?)?;
    m.add_function(wrap_pyfunction!(encode_factory_reset, m)?)?;
    m.add_function(wrap_pyfunction!(encode_reboot, m)?)?;
    m.add_function(wrap_pyfunction!(encode_sync_read, m)?)?;
    m.add_function(wrap_pyfunction!(encode_fast_sync_read, m)?)?;
    m.add_function(wrap_pyfunction!(encode_sync_write, m)?)?;
    m.add_function(wrap_pyfunction!(encode_bulk_read, m)?)?;
    m.add_function(wrap_pyfunction!(encode_bulk_write, m)?)?;
    m.add_function(wrap_pyfunction!(model_table, m)?)?;
    m.add_class::<PyDecoder>()?;
    m.add_class::<PyDxlClient>()?;
    Ok(())
}
