//! A host-side client: ping/read/write/sync_write/sync_read/bulk_read/reboot over any
//! [`Transport`] (the serial port, or a fake in tests).
//!
//! Design for the RT loop: every buffer (instruction, read chunk, decoder) is allocated in
//! [`Client::new`]; a call allocates nothing. A reply is awaited until one deadline (the
//! client's timeout, typically one control period), never a fixed 34 ms as in the SDK.
//! Multi-reply instructions (SYNC_READ, BULK_READ) collect status packets into caller slots
//! by ID until all arrived or the deadline passed, so one silent servo costs one period, not
//! the whole bus. No `tcflush` per transaction: only after a reply was abandoned at its
//! deadline does the next transaction drain the input, so late bytes never pose as a reply.
use core::fmt;
use std::io;
use std::time::{Duration, Instant};

use crate::packet::{BulkEntry, DecodeError, EncodeError, Kind, Packet, Protocol, ServoError};
use crate::decoder::AnyDecoder;
use crate::serial::SerialPort;
use crate::{instruction as ins, protocol1 as p1, protocol2 as p2};

/// The byte pipe a client talks through.
pub trait Transport {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Read what is available, waiting until `deadline`; `Ok(0)` when it passed.
    fn read(&mut self, buf: &mut [u8], deadline: Instant) -> io::Result<usize>;
}

impl Transport for SerialPort {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        SerialPort::write_all(self, bytes)
    }

    fn read(&mut self, buf: &mut [u8], deadline: Instant) -> io::Result<usize> {
        SerialPort::read(self, buf, deadline)
    }
}

#[derive(Debug)]
pub enum ClientError {
    Io(io::Error),
    Encode(EncodeError),
    /// No (valid) status from `id` before the deadline; `last_decode_error` tells whether
    /// bytes did arrive but were corrupt.
    Timeout { id: u8, last_decode_error: Option<DecodeError> },
    /// The servo answered with an error (P2 error number, P1 failure bits).
    Servo { id: u8, error: ServoError },
    /// The reply carried a different number of data bytes than requested.
    ReplyLength { id: u8, actual: usize, expected: usize },
    /// The instruction does not exist in this protocol (e.g. REBOOT on P1).
    Unsupported { instruction: &'static str, protocol: Protocol },
}

impl fmt::Display for ClientError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ClientError::Io(e) => write!(f, "serial I/O error: {e}"),
            ClientError::Encode(e) => write!(f, "cannot encode instruction: {e}"),
            ClientError::Timeout { id, last_decode_error: None } => write!(f, "no reply from servo {id} before the deadline"),
            ClientError::Timeout { id, last_decode_error: Some(e) } => {
                write!(f, "no valid reply from servo {id} before the deadline (last framing error: {e})")
            }
            ClientError::Servo { id, error } => write!(f, "servo {id} reported {error}"),
            ClientError::ReplyLength { id, actual, expected } => {
                write!(f, "servo {id} returned {actual} data bytes, expected {expected}")
            }
            ClientError::Unsupported { instruction, protocol } => {
                write!(f, "{instruction} does not exist in Protocol {}.0", protocol.number())
            }
        }
    }
}

impl std::error::Error for ClientError {}

impl From<io::Error> for ClientError {
    fn from(e: io::Error) -> Self {
        ClientError::Io(e)
    }
}

impl From<EncodeError> for ClientError {
    fn from(e: EncodeError) -> Self {
        ClientError::Encode(e)
    }
}

/// What a PING returns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PingInfo {
    pub model_number: u16,
    /// P2 only (P1's ping carries no data; the model number is read from address 0).
    pub firmware: Option<u8>,
}

/// The outcome for one ID of a SYNC_READ/BULK_READ.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Slot {
    /// No status before the deadline.
    #[default]
    Missing,
    /// A status arrived; its data is in the caller's buffer unless `error.is_failure()`.
    Received(ServoError),
    /// A status arrived with the wrong number of data bytes (data left untouched).
    BadLength { actual: usize },
}

pub struct Client<T: Transport> {
    transport: T,
    protocol: Protocol,
    timeout: Duration,
    tx: Box<[u8]>,
    rx: Box<[u8]>,
    codec: AnyDecoder,
    /// A reply was abandoned at its deadline: its late bytes may still arrive, so the next
    /// transaction drains the input first. Normal cycles skip this (no flush per cycle).
    abandoned: bool,
}

fn p1_field(field: &'static str, value: u16) -> Result<u8, ClientError> {
    u8::try_from(value).map_err(|_| EncodeError::FieldRange { field, value: value.into(), maximum: 255 }.into())
}

impl<T: Transport> Client<T> {
    /// `timeout`: how long to wait for replies after an instruction is written.
    pub fn new(transport: T, protocol: Protocol, timeout: Duration) -> Client<T> {
        let max_packet = match protocol {
            Protocol::V1 => p1::MAX_PACKET_LEN,
            Protocol::V2 => p2::MAX_PACKET_LEN,
        };
        let codec = AnyDecoder::new(protocol, p1::Expect::Status);
        Client {
            transport,
            protocol,
            timeout,
            tx: vec![0; max_packet].into_boxed_slice(),
            rx: vec![0; 256].into_boxed_slice(),
            codec,
            abandoned: false,
        }
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    pub fn transport(&self) -> &T {
        &self.transport
    }

    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    /// Encode into the TX buffer and send; returns the reply deadline.
    fn send(&mut self, encode: impl FnOnce(&mut [u8]) -> Result<usize, EncodeError>) -> Result<Instant, ClientError> {
        let n = encode(&mut self.tx)?;
        if self.abandoned {
            while self.transport.read(&mut self.rx, Instant::now())? > 0 {}
            self.abandoned = false;
        }
        self.codec.clear();
        self.transport.write_all(&self.tx[..n])?;
        Ok(Instant::now() + self.timeout)
    }

    /// Feed status packets to `on_status(id, error, params)` until it returns true (done)
    /// or the deadline passes (then `Ok(false)`). Returns the last framing error seen.
    fn collect(
        &mut self,
        deadline: Instant,
        mut on_status: impl FnMut(u8, ServoError, &[u8]) -> bool,
    ) -> Result<(bool, Option<DecodeError>), ClientError> {
        let mut last_error = None;
        loop {
            while let Some(item) = self.codec.next() {
                match item {
                    Ok(Packet { id, kind: Kind::Status(error), params }) => {
                        if on_status(id, error, params) {
                            return Ok((true, last_error));
                        }
                    }
                    Ok(_) => {} // an instruction echoed on a half-duplex line: not for us
                    Err(e) => last_error = Some(e),
                }
            }
            let n = self.transport.read(&mut self.rx, deadline)?;
            if n == 0 {
                self.abandoned = true;
                return Ok((false, last_error));
            }
            self.codec.push(&self.rx[..n]);
        }
    }

    /// Wait for one status from `id`; `on_params` sees its data when it did not fail.
    fn await_status(
        &mut self,
        id: u8,
        deadline: Instant,
        mut on_params: impl FnMut(&[u8]) -> Result<(), ClientError>,
    ) -> Result<ServoError, ClientError> {
        let mut outcome = None;
        let (done, last) = self.collect(deadline, |from, error, params| {
            if from != id {
                return false;
            }
            outcome = Some(if error.is_failure() {
                Err(ClientError::Servo { id, error })
            } else {
                on_params(params).map(|()| error)
            });
            true
        })?;
        match (done, outcome) {
            (true, Some(result)) => result,
            _ => Err(ClientError::Timeout { id, last_decode_error: last }),
        }
    }

    /// PING `id`: its model number (and firmware version on P2).
    pub fn ping(&mut self, id: u8) -> Result<PingInfo, ClientError> {
        let deadline = match self.protocol {
            Protocol::V1 => self.send(|b| p1::encode_ping(b, id))?,
            Protocol::V2 => self.send(|b| p2::encode_ping(b, id))?,
        };
        let mut info = PingInfo { model_number: 0, firmware: None };
        self.await_status(id, deadline, |p| {
            if let [lo, hi, fw, ..] = *p {
                info = PingInfo { model_number: u16::from_le_bytes([lo, hi]), firmware: Some(fw) };
            }
            Ok(())
        })?;
        if self.protocol == Protocol::V1 {
            let mut model = [0u8; 2];
            self.read(id, 0, &mut model)?;
            info.model_number = u16::from_le_bytes(model);
        }
        Ok(info)
    }

    /// READ `out.len()` bytes at `address` of `id` into `out`; returns the status (alert bit).
    pub fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<ServoError, ClientError> {
        let len = out.len();
        let deadline = match self.protocol {
            Protocol::V1 => {
                let (a, l) = (p1_field("address", address)?, p1_field("length", len as u16)?);
                self.send(|b| p1::encode_read(b, id, a, l))?
            }
            Protocol::V2 => {
                let l = u16::try_from(len).map_err(|_| EncodeError::TooLong { length: len, maximum: u16::MAX as usize })?;
                self.send(|b| p2::encode_read(b, id, address, l))?
            }
        };
        self.await_status(id, deadline, |p| {
            if p.len() != len {
                return Err(ClientError::ReplyLength { id, actual: p.len(), expected: len });
            }
            out.copy_from_slice(p);
            Ok(())
        })
    }

    fn write_with(&mut self, instruction: u8, id: u8, address: u16, data: &[u8]) -> Result<Option<ServoError>, ClientError> {
        let deadline = match self.protocol {
            Protocol::V1 => {
                let a = p1_field("address", address)?;
                self.send(|b| p1::encode_instruction_addressed(b, id, instruction, a, data))?
            }
            Protocol::V2 => self.send(|b| p2::encode_addressed(b, id, instruction, address, data))?,
        };
        if id == p2::BROADCAST_ID {
            return Ok(None); // a broadcast WRITE is never answered
        }
        self.await_status(id, deadline, |_| Ok(())).map(Some)
    }

    /// WRITE `data` at `address`; waits for the status unless `id` is broadcast (then `None`).
    pub fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<Option<ServoError>, ClientError> {
        self.write_with(ins::WRITE, id, address, data)
    }

    /// REG_WRITE: like WRITE, executed at the next ACTION.
    pub fn reg_write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<Option<ServoError>, ClientError> {
        self.write_with(ins::REG_WRITE, id, address, data)
    }

    /// ACTION: run registered writes (no reply is awaited, as in the SDK).
    pub fn action(&mut self, id: u8) -> Result<(), ClientError> {
        match self.protocol {
            Protocol::V1 => self.send(|b| p1::encode_action(b, id))?,
            Protocol::V2 => self.send(|b| p2::encode_action(b, id))?,
        };
        Ok(())
    }

    /// SYNC_WRITE (no reply): `data` holds `ids.len()` records of `data_len` bytes.
    pub fn sync_write(&mut self, address: u16, data_len: u16, ids: &[u8], data: &[u8]) -> Result<(), ClientError> {
        match self.protocol {
            Protocol::V1 => {
                let (a, l) = (p1_field("address", address)?, p1_field("length", data_len)?);
                self.send(|b| p1::encode_sync_write(b, a, l, ids, data))?
            }
            Protocol::V2 => self.send(|b| p2::encode_sync_write(b, address, data_len, ids, data))?,
        };
        Ok(())
    }

    /// SYNC_READ (P2): `length` bytes at `address` from each ID. Record `i` lands in
    /// `out[i*length..]`, its outcome in `slots[i]`. Returns how many statuses arrived.
    pub fn sync_read(&mut self, address: u16, length: u16, ids: &[u8], out: &mut [u8], slots: &mut [Slot]) -> Result<usize, ClientError> {
        if self.protocol == Protocol::V1 {
            return Err(ClientError::Unsupported { instruction: "SYNC_READ", protocol: Protocol::V1 });
        }
        let per = usize::from(length);
        check_outputs(out.len(), ids.len() * per, slots.len(), ids.len())?;
        let deadline = self.send(|b| p2::encode_sync_read(b, address, length, ids))?;
        self.collect_slots(deadline, ids.len(), |i| ids[i], |i| (i * per, per), out, slots)
    }

    /// BULK_READ: each entry its own ID/address/length; data lands back to back in `out`
    /// in entry order. Returns how many statuses arrived.
    pub fn bulk_read(&mut self, entries: &[BulkEntry], out: &mut [u8], slots: &mut [Slot]) -> Result<usize, ClientError> {
        let total: usize = entries.iter().map(|e| usize::from(e.length)).sum();
        check_outputs(out.len(), total, slots.len(), entries.len())?;
        let deadline = match self.protocol {
            Protocol::V1 => self.send(|b| p1::encode_bulk_read(b, entries))?,
            Protocol::V2 => self.send(|b| p2::encode_bulk_read(b, entries))?,
        };
        let offset = |i: usize| {
            let start: usize = entries[..i].iter().map(|e| usize::from(e.length)).sum();
            (start, usize::from(entries[i].length))
        };
        self.collect_slots(deadline, entries.len(), |i| entries[i].id, offset, out, slots)
    }

    /// Gather one status per slot (matched by ID) until all arrived or the deadline.
    fn collect_slots(
        &mut self,
        deadline: Instant,
        n: usize,
        id_of: impl Fn(usize) -> u8,
        range_of: impl Fn(usize) -> (usize, usize),
        out: &mut [u8],
        slots: &mut [Slot],
    ) -> Result<usize, ClientError> {
        slots[..n].fill(Slot::Missing);
        let mut received = 0;
        self.collect(deadline, |id, error, params| {
            let Some(i) = (0..n).find(|&i| id_of(i) == id && slots[i] == Slot::Missing) else {
                return false;
            };
            let (start, len) = range_of(i);
            slots[i] = if error.is_failure() {
                Slot::Received(error)
            } else if params.len() != len {
                Slot::BadLength { actual: params.len() }
            } else {
                out[start..start + len].copy_from_slice(params);
                Slot::Received(error)
            };
            received += 1;
            received == n
        })?;
        Ok(received)
    }

    /// REBOOT (P2 only); waits for the status unless `id` is broadcast.
    pub fn reboot(&mut self, id: u8) -> Result<(), ClientError> {
        if self.protocol == Protocol::V1 {
            return Err(ClientError::Unsupported { instruction: "REBOOT", protocol: Protocol::V1 });
        }
        let deadline = self.send(|b| p2::encode_reboot(b, id))?;
        if id != p2::BROADCAST_ID {
            self.await_status(id, deadline, |_| Ok(()))?;
        }
        Ok(())
    }
}

fn check_outputs(out: usize, out_needed: usize, slots: usize, slots_needed: usize) -> Result<(), ClientError> {
    if out < out_needed {
        return Err(EncodeError::DataMismatch { actual: out, expected: out_needed }.into());
    }
    if slots < slots_needed {
        return Err(EncodeError::DataMismatch { actual: slots, expected: slots_needed }.into());
    }
    Ok(())
}
