//! The loop's Dynamixel traffic: one SyncWrite of every goal per cycle, a periodic read of the
//! present positions, and the torque-off broadcast at stop.
//!
//! Why every buffer lives here from construction on: the goal data, the packet and the receive
//! slab are sized for the configured joints once, so a cycle encodes and decodes in place
//! (`dxl`'s encoders write into caller buffers, its decoders stream out of a fixed slab).
//!
//! Why a `Transport` trait of our own: the loop needs exactly "write these bytes" and "read
//! what arrives before this deadline"; the serial port implements it for the bench, and the
//! tests implement it in memory to check the packets byte by byte.
//!
//! Present positions: Protocol 2.0 uses SYNC_READ, or FAST_SYNC_READ where every servo's
//! firmware has it (`PresentRead`, chosen by `[bus] read`); Protocol 1.0 has neither, so it
//! uses BULK_READ (which the MX series supports). Replies arrive in request order within one
//! deadline.
//!
//! Fast Sync Read's one combined reply (`dxl::protocol2::fast_sync`) is read into its own slab
//! up to its length or the deadline, whichever comes first, then checked: every segment that
//! arrived whole with its running CRC and ID right is a servo's answer. A servo missing from
//! the reply is a read timeout for it *and every servo listed after it*: the protocol names a
//! segment only by its place, so a cut reply tells which servos' segments came (the first
//! ones), never that a later one would have. If a servo's followers sent their segments
//! without it, the bytes no longer match the listed order: then, as for any wrong byte (a CRC,
//! an ID, the prefix), the whole read counts as failed (`read_corrupt`) and no position of it
//! is used, not even those whose CRC held.
//!
//! Servo health: every status packet a joint's servo sends carries an error byte, and the bus
//! keeps per joint the last one and counters (`ServoHealth`): the hardware alert (P2 bit 7;
//! P1's voltage, overheating and overload bits) says the servo shut down, however the read
//! itself went. `read_register` reads one item of one servo (Torque Enable, Hardware Error
//! Status) through the same buffers. This layer only observes: what to do about an alert is
//! the loop's policy.
use dxl::protocol2::FastSyncError;
use dxl::{protocol1, protocol2, AnyDecoder, BulkEntry, DecodeError, EncodeError, Kind, Packet, Protocol, ServoError};
use std::fmt;
use std::io;

/// Bytes out, bytes in with a deadline on CLOCK_MONOTONIC; and, for a device that can be
/// unplugged, giving it up and getting it back.
pub trait Transport: Send {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what is available; if nothing is, waits until `deadline_ns` at most. `Ok(0)` means
    /// the deadline passed with nothing to read.
    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> io::Result<usize>;
    /// The device failed for good (`link_gone`): close it and start reopening it, without
    /// blocking. A transport that cannot reopen does nothing.
    fn disconnect(&mut self) {}
    /// After `disconnect`: takes a reopened device if one is ready, without blocking; true once
    /// the link is up again. A transport that cannot reopen never comes back.
    fn reconnect(&mut self) -> bool {
        false
    }
    /// What the link is, for the stats: "serial" (a device node: an adapter, or a pty), or
    /// another transport's own name.
    fn kind(&self) -> &'static str {
        "serial"
    }
}

/// An I/O error that says the device itself is gone (an unplugged adapter: EIO, ENXIO, ENODEV,
/// a hang-up, end of file), not a late or garbled reply: nothing will pass through it again.
pub fn link_gone(e: &io::Error) -> bool {
    matches!(e.raw_os_error(), Some(libc::EIO | libc::ENXIO | libc::ENODEV | libc::EBADF | libc::EPIPE))
        || matches!(e.kind(), io::ErrorKind::BrokenPipe | io::ErrorKind::UnexpectedEof | io::ErrorKind::NotConnected)
}

impl BusError {
    /// The bus's device is gone (see `link_gone`).
    pub fn link_gone(&self) -> bool {
        matches!(self, BusError::Io(e) if link_gone(e))
    }

    /// The servo did not answer (as opposed to answering badly).
    pub fn unanswered(&self) -> bool {
        matches!(self, BusError::Timeout { .. } | BusError::Io(_))
    }
}

/// Where the goal, the present position and Torque Enable live (the same for every joint: one
/// SyncWrite and one SyncRead address all of them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Registers {
    pub goal_address: u16,
    pub goal_size: u16,
    pub present_address: u16,
    pub present_size: u16,
    pub torque_enable_address: u16,
}

#[derive(Debug)]
pub enum BusError {
    Io(io::Error),
    Encode(EncodeError),
    Decode(DecodeError),
    /// These joints (by index) did not answer before the deadline.
    Timeout { missing: usize },
    /// A servo reported that the instruction failed.
    Servo { id: u8, raw: u8 },
    /// A Fast Sync Read reply that arrived with a wrong byte (see the module doc).
    FastSync(FastSyncError),
    /// A single-servo read named a joint index the bus does not have, or an item size other
    /// than 1..=4 bytes.
    BadRequest { index: usize, size: u16 },
}

impl fmt::Display for BusError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusError::Io(e) => write!(f, "serial I/O failed: {e}"),
            BusError::Encode(e) => write!(f, "cannot encode the packet: {e}"),
            BusError::Decode(e) => write!(f, "bad reply: {e}"),
            BusError::Timeout { missing } => write!(f, "{missing} servo(s) did not answer in time"),
            BusError::Servo { id, raw } => write!(f, "servo {id} reported error 0x{raw:02X}"),
            BusError::FastSync(e) => write!(f, "bad Fast Sync Read reply: {e:?}"),
            BusError::BadRequest { index, size } => write!(f, "no joint {index}, or an item of {size} bytes, to read"),
        }
    }
}

impl std::error::Error for BusError {}

/// Where a bus error of the loop came from, for the stats' `bus_error_kinds`: a user who sees
/// bus errors must be able to tell a servo's silence from a corrupt wire or a dead port.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BusErrorKind {
    /// The cycle's SyncWrite could not be written.
    Write,
    /// A read's replies did not all arrive before its deadline.
    ReadTimeout,
    /// A reply failed its CRC/checksum or framing.
    ReadCorrupt,
    /// A servo answered the read with an error status.
    ReadServoError,
    /// The read request could not go out, or the port failed while reading.
    ReadIo,
}

impl BusErrorKind {
    pub const ALL: [BusErrorKind; 5] = [
        BusErrorKind::Write,
        BusErrorKind::ReadTimeout,
        BusErrorKind::ReadCorrupt,
        BusErrorKind::ReadServoError,
        BusErrorKind::ReadIo,
    ];

    pub fn name(self) -> &'static str {
        match self {
            BusErrorKind::Write => "write",
            BusErrorKind::ReadTimeout => "read_timeout",
            BusErrorKind::ReadCorrupt => "read_corrupt",
            BusErrorKind::ReadServoError => "read_servo_error",
            BusErrorKind::ReadIo => "read_io",
        }
    }
}

impl BusError {
    /// The kind of a failed read (`read_present`, `read_register`).
    pub fn read_kind(&self) -> BusErrorKind {
        match self {
            BusError::Timeout { .. } => BusErrorKind::ReadTimeout,
            BusError::Decode(_) | BusError::FastSync(_) => BusErrorKind::ReadCorrupt,
            BusError::Servo { .. } => BusErrorKind::ReadServoError,
            BusError::Io(_) | BusError::Encode(_) | BusError::BadRequest { .. } => BusErrorKind::ReadIo,
        }
    }
}

/// `[bus] read`: how the loop reads the present positions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ReadChoice {
    /// Fast Sync Read where every joint's model has it (Protocol 2.0), tried at start; Sync
    /// Read (Bulk Read on Protocol 1.0) otherwise, or when the start's Fast Sync Read goes
    /// unanswered or garbled.
    #[default]
    Auto,
    /// Fast Sync Read, no fallback: the start fails if it goes unanswered.
    Fast,
    /// Sync Read (Bulk Read on Protocol 1.0).
    Sync,
}

impl ReadChoice {
    pub const NAMES: [&'static str; 3] = ["auto", "fast", "sync"];

    pub fn parse(name: &str) -> Option<ReadChoice> {
        match name {
            "auto" => Some(ReadChoice::Auto),
            "fast" => Some(ReadChoice::Fast),
            "sync" => Some(ReadChoice::Sync),
            _ => None,
        }
    }
}

/// The read the bus uses now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PresentRead {
    /// One status packet per servo: SYNC_READ (P2) or BULK_READ (P1).
    PerServo,
    /// One combined status packet: FAST_SYNC_READ (P2 only).
    Fast,
}

/// Hardware Error Status on every Protocol 2.0 model of the table (MX(2.0), XM430, XL330).
/// Protocol 1.0 has no such item: its status error byte carries the bits instead.
pub const P2_HARDWARE_ERROR_ADDRESS: u16 = 70;
/// The hardware bits of a P1 error byte (voltage 0x01, overheating 0x04, overload 0x20): the
/// same positions as in P2's Hardware Error Status, so one layout serves both.
pub const P1_HARDWARE_BITS: u8 = 0x25;

/// What the status packets of one joint's servo said so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServoHealth {
    /// The error byte of its last status packet (0: all well).
    pub last_error: u8,
    /// Status packets received from it.
    pub statuses: u64,
    /// Status packets with a non-zero error byte.
    pub errors: u64,
    /// Status packets with the hardware alert set.
    pub alerts: u64,
}

impl ServoHealth {
    fn note(&mut self, error: ServoError) {
        let raw = error.raw();
        self.last_error = raw;
        self.statuses += 1;
        self.errors += u64::from(raw != 0);
        self.alerts += u64::from(error.alert());
    }

    /// The last status packet had the hardware alert set.
    pub fn alert(&self, protocol: Protocol) -> bool {
        match protocol {
            Protocol::V2 => self.last_error & 0x80 != 0,
            Protocol::V1 => self.last_error & P1_HARDWARE_BITS != 0,
        }
    }
}

pub struct JointBus {
    protocol: Protocol,
    regs: Registers,
    ids: Vec<u8>,
    entries: Vec<BulkEntry>,
    data: Vec<u8>,
    packet: Vec<u8>,
    rx: Vec<u8>,
    decoder: AnyDecoder,
    present: Vec<i64>,
    answered: Vec<bool>,
    health: Vec<ServoHealth>,
    /// The joints of this cycle's present-position read (a subset: see `read_present_of`).
    read_ids: Vec<u8>,
    read_entries: Vec<BulkEntry>,
    read_joints: Vec<usize>,
    read: PresentRead,
    /// `ReadChoice::Auto` chose Fast Sync Read: the first read may still fall back.
    may_fall_back: bool,
    fell_back: bool,
    /// A whole Fast Sync Read reply for every joint.
    fast_rx: Vec<u8>,
}

/// Little-endian two's complement of `value` in `out` (1, 2 or 4 bytes).
fn put_le(out: &mut [u8], value: i64) {
    let bytes = value.to_le_bytes();
    out.copy_from_slice(&bytes[..out.len()]);
}

/// The register's value: 4-byte registers are signed (P2 multi-turn), shorter ones unsigned.
fn get_le(bytes: &[u8]) -> i64 {
    match bytes.len() {
        4 => i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as i64,
        _ => bytes.iter().rev().fold(0i64, |acc, &b| (acc << 8) | b as i64),
    }
}

impl JointBus {
    pub fn new(protocol: Protocol, regs: Registers, ids: &[u8]) -> Self {
        let n = ids.len();
        let widest = usize::from(regs.goal_size.max(regs.present_size).max(1));
        let decoder = AnyDecoder::new(protocol, protocol1::Expect::Status);
        JointBus {
            protocol,
            regs,
            ids: ids.to_vec(),
            entries: ids
                .iter()
                .map(|&id| BulkEntry { id, address: regs.present_address, length: regs.present_size })
                .collect(),
            data: vec![0; n * widest],
            // Worst case: every byte stuffed (P2), plus headers; generous and allocated once.
            packet: vec![0; 64 + 2 * n * (widest + 6)],
            rx: vec![0; 256],
            decoder,
            present: vec![-1; n],
            answered: vec![false; n],
            health: vec![ServoHealth::default(); n],
            read_ids: Vec::with_capacity(n),
            read_entries: Vec::with_capacity(n),
            read_joints: Vec::with_capacity(n),
            read: PresentRead::PerServo,
            may_fall_back: false,
            fell_back: false,
            fast_rx: vec![0; protocol2::fast_sync_reply_len(n, usize::from(regs.present_size))],
        }
    }

    /// Sets the read from `[bus] read` and whether every joint's model has Fast Sync Read:
    /// `Fast` only on Protocol 2.0 (the configuration checks it asked for no more).
    pub fn choose_read(&mut self, choice: ReadChoice, models_have_fast: bool) {
        let fast = self.protocol == Protocol::V2 && models_have_fast && choice != ReadChoice::Sync;
        self.read = if fast { PresentRead::Fast } else { PresentRead::PerServo };
        self.may_fall_back = fast && choice == ReadChoice::Auto;
        self.fell_back = false;
    }

    /// The start's first read: with `auto`'s Fast Sync Read, one read before `deadline_ns`;
    /// if it is not answered whole and right, the bus reads with Sync Read from then on
    /// (`fell_back`). A lost link is an error; anything else is left to the start's own reads.
    pub fn settle_read(&mut self, t: &mut dyn Transport, deadline_ns: u64) -> Result<(), BusError> {
        if !std::mem::take(&mut self.may_fall_back) {
            return Ok(());
        }
        match self.read_present_of(t, deadline_ns, |_| true) {
            Err(e) if e.link_gone() => Err(e),
            Err(_) => {
                self.read = PresentRead::PerServo;
                self.fell_back = true;
                Ok(())
            }
            Ok(()) => Ok(()),
        }
    }

    /// The read in use, by its instruction's name: "fast_sync_read", "sync_read" or "bulk_read".
    pub fn read_name(&self) -> &'static str {
        match (self.read, self.protocol) {
            (PresentRead::Fast, _) => "fast_sync_read",
            (PresentRead::PerServo, Protocol::V2) => "sync_read",
            (PresentRead::PerServo, Protocol::V1) => "bulk_read",
        }
    }

    /// `auto`'s Fast Sync Read went unanswered at start and the bus fell back to Sync Read.
    pub fn fell_back(&self) -> bool {
        self.fell_back
    }

    pub fn ids(&self) -> &[u8] {
        &self.ids
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// Per joint (in joint order), what its servo's status packets said.
    pub fn health(&self) -> &[ServoHealth] {
        &self.health
    }


    fn sync_write(&mut self, t: &mut dyn Transport, address: u16, size: u16) -> Result<(), BusError> {
        let data = &self.data[..self.ids.len() * usize::from(size)];
        let n = match self.protocol {
            Protocol::V1 => protocol1::encode_sync_write(&mut self.packet, address as u8, size as u8, &self.ids, data),
            Protocol::V2 => protocol2::encode_sync_write(&mut self.packet, address, size, &self.ids, data),
        }
        .map_err(BusError::Encode)?;
        t.write_all(&self.packet[..n]).map_err(BusError::Io)
    }

    /// One SyncWrite of every joint's goal tick (`goals` in joint order).
    pub fn write_goals(&mut self, t: &mut dyn Transport, goals: &[i64]) -> Result<(), BusError> {
        let size = usize::from(self.regs.goal_size);
        for (chunk, &goal) in self.data.chunks_mut(size).zip(goals) {
            put_le(chunk, goal);
        }
        self.sync_write(t, self.regs.goal_address, self.regs.goal_size)
    }

    /// Torque Enable on every joint, in one SyncWrite.
    pub fn set_torque(&mut self, t: &mut dyn Transport, enable: bool) -> Result<(), BusError> {
        self.data[..self.ids.len()].fill(u8::from(enable));
        self.sync_write(t, self.regs.torque_enable_address, 1)
    }

    /// Reads every joint's present position before `deadline_ns`; ticks in joint order.
    pub fn read_present(&mut self, t: &mut dyn Transport, deadline_ns: u64) -> Result<&[i64], BusError> {
        self.read_present_of(t, deadline_ns, |_| true)?;
        Ok(&self.present)
    }

    /// Reads the present position of the joints `include` selects (one SYNC_READ or BULK_READ;
    /// a servo known to be silent is left out, so the read need not wait for its deadline).
    /// Whatever happens, `answered()` then says which of them answered and `present()` holds
    /// their ticks: a servo that does not answer costs the others nothing. `Ok` when every
    /// selected servo answered, and when none was selected.
    pub fn read_present_of(&mut self, t: &mut dyn Transport, deadline_ns: u64, include: impl Fn(usize) -> bool) -> Result<(), BusError> {
        self.answered.fill(false);
        self.read_ids.clear();
        self.read_entries.clear();
        self.read_joints.clear();
        for (k, entry) in self.entries.iter().enumerate().filter(|(k, _)| include(*k)) {
            self.read_ids.push(entry.id);
            self.read_entries.push(*entry);
            self.read_joints.push(k);
        }
        if self.read_ids.is_empty() {
            return Ok(());
        }
        self.discard_input(t)?;
        if self.read == PresentRead::Fast {
            return self.fast_sync_read(t, deadline_ns);
        }
        let n = match self.protocol {
            Protocol::V1 => protocol1::encode_bulk_read(&mut self.packet, &self.read_entries),
            Protocol::V2 => protocol2::encode_sync_read(
                &mut self.packet,
                self.regs.present_address,
                self.regs.present_size,
                &self.read_ids,
            ),
        }
        .map_err(BusError::Encode)?;
        t.write_all(&self.packet[..n]).map_err(BusError::Io)?;
        let mut pending = self.read_ids.len();
        let mut first_error = None;
        while pending > 0 {
            let got = t.read_until(&mut self.rx, deadline_ns).map_err(BusError::Io)?;
            if got == 0 {
                return Err(first_error.unwrap_or(BusError::Timeout { missing: pending }));
            }
            self.decoder.push(&self.rx[..got]);
            while let Some(item) = self.decoder.next() {
                note_status(&mut self.health, &self.ids, &item);
                match accept(item, &self.read_ids, usize::from(self.regs.present_size)) {
                    Ok(Some((r, tick))) if !self.answered[self.read_joints[r]] => {
                        let k = self.read_joints[r];
                        self.answered[k] = true;
                        self.present[k] = tick;
                        pending -= 1;
                    }
                    Ok(_) => {}
                    Err(e) => first_error = first_error.or(Some(e)),
                }
            }
        }
        match first_error {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// The selected joints' present positions in one FAST_SYNC_READ (see the module doc for
    /// what a cut or garbled reply means). Allocates nothing; never indexes past its slabs.
    fn fast_sync_read(&mut self, t: &mut dyn Transport, deadline_ns: u64) -> Result<(), BusError> {
        let (x, n) = (usize::from(self.regs.present_size), self.read_ids.len());
        let (address, size) = (self.regs.present_address, self.regs.present_size);
        let length = protocol2::encode_fast_sync_read(&mut self.packet, address, size, &self.read_ids).map_err(BusError::Encode)?;
        t.write_all(&self.packet[..length]).map_err(BusError::Io)?;
        let want = protocol2::fast_sync_reply_len(n, x).min(self.fast_rx.len());
        let prefix = protocol2::fast_sync_reply_prefix(n, x);
        let mut have = 0;
        while have < want {
            let got = t.read_until(&mut self.fast_rx[have..want], deadline_ns).map_err(BusError::Io)?;
            if got == 0 {
                break;
            }
            have = skip_to_prefix(&mut self.fast_rx, have + got, &prefix);
        }
        let (health, answered, present, joints, ids) = (&mut self.health, &mut self.answered, &mut self.present, &self.read_joints, &self.read_ids);
        let mut refused = None;
        let whole = protocol2::decode_fast_sync_prefix(&self.fast_rx[..have], ids, x, |r, raw, data| {
            let (Some(&k), Some(&id)) = (joints.get(r), ids.get(r)) else { return };
            let error = ServoError::V2(protocol2::StatusError::from_raw(raw));
            if let Some(h) = health.get_mut(k) {
                h.note(error);
            }
            if error.is_failure() {
                refused.get_or_insert((id, raw));
            } else if let (Some(a), Some(p)) = (answered.get_mut(k), present.get_mut(k)) {
                *a = true;
                *p = get_le(data);
            }
        })
        .map_err(BusError::FastSync)?;
        match refused {
            Some((id, raw)) => Err(BusError::Servo { id, raw }),
            None if whole < n => Err(BusError::Timeout { missing: n - whole }),
            None => Ok(()),
        }
    }

    /// Per joint: whether it answered the last present-position read.
    pub fn answered(&self) -> &[bool] {
        &self.answered
    }

    /// Per joint: its last present position read (−1 before the first).
    pub fn present(&self) -> &[i64] {
        &self.present
    }

    /// Joint `k`'s present position alone (a re-anchor after a recovery).
    pub fn read_present_one(&mut self, t: &mut dyn Transport, k: usize, deadline_ns: u64) -> Result<i64, BusError> {
        let tick = self.read_register(t, k, self.regs.present_address, self.regs.present_size, deadline_ns)?;
        self.present[k] = tick;
        Ok(tick)
    }

    /// REBOOT joint `k`'s servo (Protocol 2.0; 1.0 has none). Its status packet is read if it
    /// comes before `deadline_ns`; the servo is silent afterwards anyway, so none is not an error.
    pub fn reboot(&mut self, t: &mut dyn Transport, k: usize, deadline_ns: u64) -> Result<(), BusError> {
        let id = *self.ids.get(k).ok_or(BusError::BadRequest { index: k, size: 0 })?;
        if self.protocol != Protocol::V2 {
            return Err(BusError::BadRequest { index: k, size: 0 });
        }
        self.discard_input(t)?;
        let n = protocol2::encode_reboot(&mut self.packet, id).map_err(BusError::Encode)?;
        t.write_all(&self.packet[..n]).map_err(BusError::Io)?;
        match self.await_status(t, k, 0, deadline_ns) {
            Ok(_) | Err(BusError::Timeout { .. }) => Ok(()),
            Err(e) => Err(e),
        }
    }

    /// Torque Enable of joint `k`'s servo alone (a WRITE, its status packet awaited).
    pub fn write_torque(&mut self, t: &mut dyn Transport, k: usize, enable: bool, deadline_ns: u64) -> Result<(), BusError> {
        let id = *self.ids.get(k).ok_or(BusError::BadRequest { index: k, size: 1 })?;
        self.discard_input(t)?;
        let value = [u8::from(enable)];
        let address = self.regs.torque_enable_address;
        let n = match self.protocol {
            Protocol::V1 => protocol1::encode_write(&mut self.packet, id, address as u8, &value),
            Protocol::V2 => protocol2::encode_write(&mut self.packet, id, address, &value),
        }
        .map_err(BusError::Encode)?;
        t.write_all(&self.packet[..n]).map_err(BusError::Io)?;
        self.await_status(t, k, 0, deadline_ns).map(drop)
    }

    /// Reads one item (`size` 1, 2 or 4 bytes at `address`) of joint `k`'s servo before
    /// `deadline_ns`; 4-byte items are signed. Allocates nothing, so the loop may call it.
    pub fn read_register(&mut self, t: &mut dyn Transport, k: usize, address: u16, size: u16, deadline_ns: u64) -> Result<i64, BusError> {
        let Some(&id) = self.ids.get(k).filter(|_| (1..=4).contains(&size)) else {
            return Err(BusError::BadRequest { index: k, size });
        };
        self.discard_input(t)?;
        let n = match self.protocol {
            Protocol::V1 => match (u8::try_from(address), u8::try_from(size)) {
                (Ok(a), Ok(l)) => protocol1::encode_read(&mut self.packet, id, a, l),
                _ => Err(EncodeError::FieldRange { field: "P1 address", value: u32::from(address), maximum: 255 }),
            },
            Protocol::V2 => protocol2::encode_read(&mut self.packet, id, address, size),
        }
        .map_err(BusError::Encode)?;
        t.write_all(&self.packet[..n]).map_err(BusError::Io)?;
        self.await_status(t, k, usize::from(size), deadline_ns)
    }

    /// Waits for joint `k`'s status packet with exactly `size` bytes of data (see `accept`);
    /// the value of those bytes (0 when `size` is 0).
    fn await_status(&mut self, t: &mut dyn Transport, k: usize, size: usize, deadline_ns: u64) -> Result<i64, BusError> {
        let mut first_error = None;
        loop {
            let got = t.read_until(&mut self.rx, deadline_ns).map_err(BusError::Io)?;
            if got == 0 {
                return Err(first_error.unwrap_or(BusError::Timeout { missing: 1 }));
            }
            self.decoder.push(&self.rx[..got]);
            while let Some(item) = self.decoder.next() {
                note_status(&mut self.health, &self.ids, &item);
                match accept(item, &self.ids[k..=k], size) {
                    Ok(Some((_, value))) => return Ok(value),
                    Ok(None) => {}
                    // The servo answered and refused: no other reply will come.
                    Err(e @ BusError::Servo { .. }) => return Err(e),
                    Err(e) => first_error = first_error.or(Some(e)),
                }
            }
        }
    }

    /// Torque Enable of joint `k`'s servo (true: on).
    pub fn read_torque_enable(&mut self, t: &mut dyn Transport, k: usize, deadline_ns: u64) -> Result<bool, BusError> {
        self.read_register(t, k, self.regs.torque_enable_address, 1, deadline_ns).map(|v| v != 0)
    }

    /// The hardware error bits of joint `k`'s servo, in P2's Hardware Error Status layout (0x01
    /// input voltage, 0x04 overheating, 0x08 encoder, 0x10 electrical shock, 0x20 overload).
    /// Protocol 1.0 has no such item: its bits come from the error byte of a Torque Enable read.
    pub fn read_hardware_error(&mut self, t: &mut dyn Transport, k: usize, deadline_ns: u64) -> Result<u8, BusError> {
        match self.protocol {
            Protocol::V2 => self.read_register(t, k, P2_HARDWARE_ERROR_ADDRESS, 1, deadline_ns).map(|v| v as u8),
            Protocol::V1 => {
                self.read_register(t, k, self.regs.torque_enable_address, 1, deadline_ns)?;
                Ok(self.health[k].last_error & P1_HARDWARE_BITS)
            }
        }
    }

    /// Drops bytes left over from an earlier, late reply so they cannot pass for this one.
    fn discard_input(&mut self, t: &mut dyn Transport) -> Result<(), BusError> {
        self.decoder.clear();
        while t.read_until(&mut self.rx, 0).map_err(BusError::Io)? > 0 {}
        Ok(())
    }
}

/// Drops the bytes before the first place `buf[..have]` could start `prefix` (a late reply,
/// line noise); the bytes kept.
fn skip_to_prefix(buf: &mut [u8], have: usize, prefix: &[u8]) -> usize {
    let have = have.min(buf.len());
    let start = (0..have)
        .find(|&i| {
            let m = (have - i).min(prefix.len());
            buf[i..i + m] == prefix[..m]
        })
        .unwrap_or(have);
    buf.copy_within(start..have, 0);
    have - start
}

/// Notes the error byte of a status packet from one of our servos in its joint's health.
fn note_status(health: &mut [ServoHealth], ids: &[u8], item: &Result<Packet<'_>, DecodeError>) {
    if let Ok(Packet { id, kind: Kind::Status(error), .. }) = item {
        if let Some(k) = ids.iter().position(|i| i == id) {
            health[k].note(*error);
        }
    }
}

/// A status packet answering our read: (joint index, tick); `Ok(None)` for anything else.
fn accept(item: Result<Packet<'_>, DecodeError>, ids: &[u8], size: usize) -> Result<Option<(usize, i64)>, BusError> {
    let packet = item.map_err(BusError::Decode)?;
    let Kind::Status(error) = packet.kind else { return Ok(None) };
    let Some(k) = ids.iter().position(|&id| id == packet.id) else { return Ok(None) };
    if error.is_failure() {
        return Err(BusError::Servo { id: packet.id, raw: error.raw() });
    }
    // Exactly the size asked for: a status carries no address, so a late reply to an earlier
    // request (a SyncRead's four bytes arriving during a one-byte read) is told apart by its length.
    // A late reply of the same length (a one-byte Torque Enable during a one-byte Hardware Error
    // read) cannot be: nothing on the wire tells them apart.
    if packet.params.len() != size {
        return Ok(None);
    }
    Ok(Some((k, get_le(packet.params))))
}

#[cfg(test)]
pub(crate) mod memory {
    //! An in-memory bus for the tests: records every packet written and answers reads of the
    //! present position from a table, like servos would.
    use super::*;
    use std::collections::VecDeque;
    use std::sync::{Arc, Mutex};

    /// Servos on a wire: present positions, one-byte registers, REBOOT and silence.
    ///
    /// A servo listed in `present` answers SYNC_READ/BULK_READ and single READs of its present
    /// position, READs of Torque Enable (64, or 24 on Protocol 1.0: `torque`, default on) and
    /// Hardware Error Status (70: `hardware`), WRITEs of Torque Enable, and REBOOT (which
    /// clears its hardware error and turns torque off, then leaves it silent for
    /// `reboot_silence` transactions). A servo in `silent` answers nothing. `items` overrides
    /// any one-byte READ: (id, address, value).
    #[derive(Default)]
    pub struct Wire {
        pub written: Vec<Vec<u8>>,
        pub present: Vec<(u8, i64)>,
        pub replies: VecDeque<u8>,
        /// Writes time out (a stalled adapter: the link stays).
        pub fail_writes: bool,
        /// The adapter is unplugged: every write and read fails with EIO until it is back.
        pub unplugged: bool,
        pub disconnects: u64,
        pub protocol2: bool,
        /// The error byte of every status packet (besides the hardware error's alert).
        pub error: u8,
        /// One-byte items a READ answers: (id, address, value).
        pub items: Vec<(u8, u16, u8)>,
        /// Torque Enable per id (absent: on).
        pub torque: Vec<(u8, bool)>,
        /// Hardware Error Status per id (absent: 0); non-zero sets the alert on its statuses.
        pub hardware: Vec<(u8, u8)>,
        pub silent: Vec<u8>,
        /// Transactions a rebooted servo stays silent for.
        pub reboot_silence: u32,
        pub rebooting: Vec<(u8, u32)>,
        pub reboots: Vec<u8>,
        /// Bytes of a late reply still in flight: they arrive just before the next reply.
        pub late: Vec<u8>,
        /// Encoder glitches: (id, offset) added to that servo's next present-position reply only.
        pub glitches: Vec<(u8, i64)>,
        /// The servos' firmware lacks FAST_SYNC_READ: they ignore it.
        pub no_fast_sync_read: bool,
        /// A Fast Sync Read's reply as the host receives it: `Some(f)` passes the servos'
        /// reply through `f` (a flipped byte, a cut, noise before it).
        pub garble_fast: Option<fn(Vec<u8>) -> Vec<u8>>,
    }

    impl Wire {
        fn value_of(list: &[(u8, u8)], id: u8, default: u8) -> u8 {
            list.iter().find(|(i, _)| *i == id).map_or(default, |e| e.1)
        }

        fn set(list: &mut Vec<(u8, u8)>, id: u8, value: u8) {
            list.retain(|(i, _)| *i != id);
            list.push((id, value));
        }

        pub fn torque_of(&self, id: u8) -> bool {
            self.torque.iter().find(|(i, _)| *i == id).is_none_or(|e| e.1)
        }

        pub fn set_torque(&mut self, id: u8, on: bool) {
            self.torque.retain(|(i, _)| *i != id);
            self.torque.push((id, on));
        }

        pub fn set_hardware(&mut self, id: u8, bits: u8) {
            Self::set(&mut self.hardware, id, bits);
        }

        pub fn hardware_of(&self, id: u8) -> u8 {
            Self::value_of(&self.hardware, id, 0)
        }

        fn answers(&mut self, id: u8) -> bool {
            if self.silent.contains(&id) || !self.present.iter().any(|p| p.0 == id) {
                return false;
            }
            if let Some(left) = self.rebooting.iter_mut().find(|r| r.0 == id) {
                if left.1 > 0 {
                    left.1 -= 1;
                    return false;
                }
            }
            self.rebooting.retain(|r| r.0 != id || r.1 > 0);
            true
        }

        /// The tick a present-position read of `id` answers now (a queued glitch once).
        fn present_reply(&mut self, id: u8) -> i64 {
            let tick = self.present.iter().find(|p| p.0 == id).map_or(0, |p| p.1);
            match self.glitches.iter().position(|g| g.0 == id) {
                Some(i) => tick + self.glitches.remove(i).1,
                None => tick,
            }
        }
    }

    #[derive(Clone, Default)]
    pub struct MemoryTransport(pub Arc<Mutex<Wire>>);

    impl MemoryTransport {
        pub fn new(protocol2: bool, present: &[(u8, i64)]) -> Self {
            let wire = Wire { present: present.to_vec(), protocol2, ..Default::default() };
            MemoryTransport(Arc::new(Mutex::new(wire)))
        }
        pub fn written(&self) -> Vec<Vec<u8>> {
            self.0.lock().unwrap().written.clone()
        }
        pub fn wire(&self) -> std::sync::MutexGuard<'_, Wire> {
            self.0.lock().unwrap()
        }
    }

    fn status(wire: &mut Wire, id: u8, data: &[u8]) {
        let mut buf = [0u8; 64];
        let hardware = wire.hardware_of(id);
        let n = if wire.protocol2 {
            let alert = if hardware != 0 { 0x80 } else { 0 };
            protocol2::encode_status(&mut buf, id, wire.error | alert, data).unwrap()
        } else {
            protocol1::encode_status(&mut buf, id, wire.error | (hardware & P1_HARDWARE_BITS), data).unwrap()
        };
        wire.replies.extend(&buf[..n]);
    }

    fn reply(wire: &mut Wire, request: &[u8]) {
        // The parameters, without the checksum (P2: 2 bytes of CRC, P1: 1 byte).
        let (id, instruction, params) = if wire.protocol2 {
            (request[4], request[7], &request[8..request.len() - 2])
        } else {
            (request[2], request[4], &request[5..request.len() - 1])
        };
        let torque_address = if wire.protocol2 { 64 } else { 24 };
        match instruction {
            0x02 => {
                let (address, length) = if wire.protocol2 {
                    (u16::from_le_bytes([params[0], params[1]]), u16::from_le_bytes([params[2], params[3]]))
                } else {
                    (u16::from(params[0]), u16::from(params[1]))
                };
                let item = wire.items.iter().find(|(i, a, _)| *i == id && *a == address).map(|item| item.2);
                if let Some(value) = item {
                    status(wire, id, &[value]);
                    return;
                }
                if !wire.answers(id) {
                    return;
                }
                match (address, length) {
                    (a, 1) if a == torque_address => {
                        let on = u8::from(wire.torque_of(id));
                        status(wire, id, &[on]);
                    }
                    (70, 1) if wire.protocol2 => {
                        let bits = wire.hardware_of(id);
                        status(wire, id, &[bits]);
                    }
                    (_, 4) => {
                        let tick = wire.present_reply(id);
                        status(wire, id, &(tick as i32).to_le_bytes());
                    }
                    (_, 2) => {
                        let tick = wire.present_reply(id);
                        status(wire, id, &(tick as u16).to_le_bytes());
                    }
                    _ => {}
                }
            }
            0x03 if wire.answers(id) => {
                let (address, value) =
                    if wire.protocol2 { (u16::from_le_bytes([params[0], params[1]]), params[2]) } else { (u16::from(params[0]), params[1]) };
                if address == torque_address {
                    // A shut-down servo takes the write and stays off (P2: until a REBOOT).
                    let on = value != 0 && wire.hardware_of(id) == 0;
                    wire.set_torque(id, on);
                }
                status(wire, id, &[]);
            }
            0x08 if wire.answers(id) => {
                status(wire, id, &[]); // answered with the alert it clears
                wire.set_hardware(id, 0);
                wire.set_torque(id, false);
                wire.reboots.push(id);
                let silence = wire.reboot_silence;
                wire.rebooting.retain(|r| r.0 != id);
                wire.rebooting.push((id, silence));
            }
            0x8A if !wire.no_fast_sync_read => {
                // One combined reply, cut at the first listed servo that does not answer.
                let mut out = protocol2::fast_sync_reply_prefix(params.len() - 4, 4).to_vec();
                let mut crc = dxl::crc16(&out);
                for &id in &params[4..] {
                    if !wire.answers(id) {
                        break;
                    }
                    let tick = wire.present_reply(id) as i32;
                    let error = wire.error | if wire.hardware_of(id) != 0 { 0x80 } else { 0 };
                    crc = protocol2::push_fast_sync_segment(&mut out, crc, id, error, &tick.to_le_bytes());
                }
                if out.len() > 8 {
                    let out = match wire.garble_fast {
                        Some(f) => f(out),
                        None => out,
                    };
                    wire.replies.extend(out);
                }
            }
            0x82 | 0x92 => {
                let listed: Vec<u8> = if instruction == 0x82 {
                    params[4..].to_vec()
                } else if wire.protocol2 {
                    params.chunks(5).map(|c| c[0]).collect()
                } else {
                    params[1..].chunks(3).map(|c| c[1]).collect()
                };
                for (id, _) in wire.present.clone() {
                    if !listed.contains(&id) || !wire.answers(id) {
                        continue;
                    }
                    let tick = wire.present_reply(id);
                    if wire.protocol2 {
                        status(wire, id, &(tick as i32).to_le_bytes());
                    } else {
                        status(wire, id, &(tick as u16).to_le_bytes());
                    }
                }
            }
            _ => {}
        }
    }

    impl Transport for MemoryTransport {
        fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
            let mut wire = self.0.lock().unwrap();
            if wire.unplugged {
                return Err(io::Error::from_raw_os_error(libc::EIO));
            }
            if wire.fail_writes {
                return Err(io::ErrorKind::TimedOut.into());
            }
            wire.written.push(bytes.to_vec());
            let late = std::mem::take(&mut wire.late);
            wire.replies.extend(late);
            reply(&mut wire, bytes);
            Ok(())
        }
        fn read_until(&mut self, buf: &mut [u8], _deadline_ns: u64) -> io::Result<usize> {
            let mut wire = self.0.lock().unwrap();
            if wire.unplugged {
                return Err(io::Error::from_raw_os_error(libc::EIO));
            }
            let n = buf.len().min(wire.replies.len());
            for b in buf.iter_mut().take(n) {
                *b = wire.replies.pop_front().unwrap();
            }
            Ok(n)
        }

        fn disconnect(&mut self) {
            self.0.lock().unwrap().disconnects += 1;
        }

        fn reconnect(&mut self) -> bool {
            !self.0.lock().unwrap().unplugged
        }
    }
}

#[cfg(test)]
mod tests {
    use super::memory::MemoryTransport;
    use super::*;

    fn regs2() -> Registers {
        Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 }
    }

    #[test]
    fn one_sync_write_carries_every_goal() {
        let mut t = MemoryTransport::new(true, &[]);
        let mut bus = JointBus::new(Protocol::V2, regs2(), &[1, 2]);
        bus.write_goals(&mut t, &[2048, -1]).unwrap();
        let written = t.written();
        assert_eq!(written.len(), 1);
        let mut want = [0u8; 64];
        let data = [0x00, 0x08, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF];
        let n = protocol2::encode_sync_write(&mut want, 116, 4, &[1, 2], &data).unwrap();
        assert_eq!(written[0], want[..n].to_vec());
    }

    #[test]
    fn present_positions_come_back_in_joint_order_for_both_protocols() {
        let mut t2 = MemoryTransport::new(true, &[(2, 1000), (1, -5)]);
        let mut bus2 = JointBus::new(Protocol::V2, regs2(), &[1, 2]);
        assert_eq!(bus2.read_present(&mut t2, 0).unwrap(), &[-5, 1000]);
        let regs1 = Registers { goal_address: 30, goal_size: 2, present_address: 36, present_size: 2, torque_enable_address: 24 };
        let mut t1 = MemoryTransport::new(false, &[(3, 4095)]);
        let mut bus1 = JointBus::new(Protocol::V1, regs1, &[3]);
        assert_eq!(bus1.read_present(&mut t1, 0).unwrap(), &[4095]);
        assert_eq!(t1.written()[0][4], 0x92, "P1 reads with BULK_READ");
    }

    proptest::proptest! {
        #[test]
        fn goals_survive_the_sync_write_codec(
            goals in proptest::collection::vec(i32::MIN as i64..=i32::MAX as i64, 1..20),
            first_id in 0u8..200,
        ) {
            let ids: Vec<u8> = (0..goals.len() as u8).map(|k| first_id + k).collect();
            let mut t = MemoryTransport::new(true, &[]);
            let mut bus = JointBus::new(Protocol::V2, regs2(), &ids);
            bus.write_goals(&mut t, &goals).unwrap();
            let mut decoder = protocol2::Decoder::new();
            decoder.push(&t.written()[0]);
            let packet = decoder.next().unwrap().unwrap();
            proptest::prop_assert_eq!(packet.kind, Kind::Instruction(0x83));
            let records = &packet.params[4..];
            for (k, (id, goal)) in ids.iter().zip(&goals).enumerate() {
                let record = &records[5 * k..5 * k + 5];
                proptest::prop_assert_eq!(record[0], *id);
                proptest::prop_assert_eq!(get_le(&record[1..]), *goal);
            }
        }

        #[test]
        fn short_registers_read_back_unsigned(value in 0i64..=0xFFFF) {
            let mut bytes = [0u8; 2];
            put_le(&mut bytes, value);
            proptest::prop_assert_eq!(get_le(&bytes), value);
        }
    }

    fn regs1() -> Registers {
        Registers { goal_address: 30, goal_size: 2, present_address: 36, present_size: 2, torque_enable_address: 24 }
    }

    #[test]
    fn an_alert_is_counted_and_the_positions_still_arrive() {
        let mut t = MemoryTransport::new(true, &[(1, 100), (2, 200)]);
        t.0.lock().unwrap().error = 0x80;
        let mut bus = JointBus::new(Protocol::V2, regs2(), &[1, 2]);
        assert_eq!(bus.read_present(&mut t, 0).unwrap(), &[100, 200], "an alert alone fails no read");
        assert_eq!(bus.health()[1], ServoHealth { last_error: 0x80, statuses: 1, errors: 1, alerts: 1 });
        assert!(bus.health()[0].alert(Protocol::V2));
        t.0.lock().unwrap().error = 0;
        bus.read_present(&mut t, 0).unwrap();
        assert_eq!(bus.health()[0], ServoHealth { last_error: 0, statuses: 2, errors: 1, alerts: 1 });
        assert!(!bus.health()[0].alert(Protocol::V2));
    }

    #[test]
    fn p1_hardware_bits_are_alerts_and_its_failure_bits_are_not() {
        let mut t = MemoryTransport::new(false, &[(3, 7)]);
        let mut bus = JointBus::new(Protocol::V1, regs1(), &[3]);
        t.0.lock().unwrap().error = 0x20; // overload
        assert_eq!(bus.read_present(&mut t, 0).unwrap(), &[7]);
        assert_eq!(bus.health()[0].alerts, 1);
        t.0.lock().unwrap().error = 0x08; // range: the read itself failed
        let error = bus.read_present(&mut t, 0).unwrap_err();
        assert!(matches!(error, BusError::Servo { id: 3, raw: 0x08 }));
        assert_eq!(error.read_kind(), BusErrorKind::ReadServoError);
        assert_eq!(bus.health()[0], ServoHealth { last_error: 0x08, statuses: 2, errors: 2, alerts: 1 });
    }

    #[test]
    fn torque_enable_and_hardware_error_are_read_per_servo() {
        let mut t = MemoryTransport::new(true, &[]);
        t.0.lock().unwrap().items = vec![(2, 64, 1), (2, 70, 0x24), (1, 64, 0)];
        let mut bus = JointBus::new(Protocol::V2, regs2(), &[1, 2]);
        assert!(bus.read_torque_enable(&mut t, 1, 0).unwrap());
        assert!(!bus.read_torque_enable(&mut t, 0, 0).unwrap());
        assert_eq!(bus.read_hardware_error(&mut t, 1, 0).unwrap(), 0x24);
        let error = bus.read_hardware_error(&mut t, 0, 0).unwrap_err();
        assert!(matches!(error, BusError::Timeout { missing: 1 }));
        assert_eq!(error.read_kind(), BusErrorKind::ReadTimeout);
        assert!(matches!(bus.read_register(&mut t, 2, 64, 1, 0), Err(BusError::BadRequest { index: 2, .. })));
        assert!(matches!(bus.read_register(&mut t, 0, 64, 5, 0), Err(BusError::BadRequest { size: 5, .. })));
        let mut want = [0u8; 16];
        let n = protocol2::encode_read(&mut want, 2, 70, 1).unwrap();
        assert!(t.written().contains(&want[..n].to_vec()), "a READ of Hardware Error Status went out");
        // Protocol 1.0: the bits ride on the status error byte of any read.
        let mut t1 = MemoryTransport::new(false, &[]);
        t1.0.lock().unwrap().items = vec![(4, 24, 0)];
        t1.0.lock().unwrap().error = 0x24;
        let mut bus1 = JointBus::new(Protocol::V1, regs1(), &[4]);
        assert_eq!(bus1.read_hardware_error(&mut t1, 0, 0).unwrap(), 0x24);
        assert!(!bus1.read_torque_enable(&mut t1, 0, 0).unwrap());
    }

    #[test]
    fn a_late_reply_of_another_length_does_not_pass_for_the_one_awaited() {
        let mut t = MemoryTransport::new(true, &[(1, 0x0802)]);
        t.wire().set_hardware(1, 0x20);
        let mut bus = JointBus::new(Protocol::V2, regs2(), &[1]);
        let mut late = [0u8; 32];
        let n = protocol2::encode_status(&mut late, 1, 0, &0x0802i32.to_le_bytes()).unwrap();
        t.wire().late = late[..n].to_vec(); // a SyncRead's reply, in flight past its deadline
        assert_eq!(bus.read_hardware_error(&mut t, 0, 0).unwrap(), 0x20, "not the tick's low byte 0x02");
        let n = protocol2::encode_status(&mut late, 1, 0, &0x0800i32.to_le_bytes()).unwrap();
        t.wire().late = late[..n].to_vec();
        assert!(bus.read_torque_enable(&mut t, 0, 0).unwrap(), "not the tick's low byte 0x00");
        t.wire().late = late[..n].to_vec();
        bus.write_torque(&mut t, 0, true, 0).unwrap();
        assert!(t.wire().replies.is_empty(), "the write waited for its own (empty) status");
    }

    #[test]
    fn hardware_error_status_sits_at_70_on_every_p2_model() {
        for model in dxl::models::MODELS.iter().filter(|m| m.protocol == Protocol::V2) {
            let item = model.item("Hardware Error Status").expect(model.name);
            assert_eq!((item.address, item.size), (P2_HARDWARE_ERROR_ADDRESS, 1), "{}", model.name);
        }
    }

    proptest::proptest! {
        #[test]
        fn every_status_error_byte_is_kept_and_counted(errors in proptest::collection::vec(proptest::prelude::any::<u8>(), 1..12), p2 in proptest::prelude::any::<bool>()) {
            let protocol = if p2 { Protocol::V2 } else { Protocol::V1 };
            let mut t = MemoryTransport::new(p2, &[(5, 9)]);
            let regs = if p2 { regs2() } else { regs1() };
            let mut bus = JointBus::new(protocol, regs, &[5]);
            let mut want = ServoHealth::default();
            for &raw in &errors {
                // P1 status bytes never have bit 7 (the SDK rejects them; our decoder too).
                let raw = if p2 { raw } else { raw & 0x7F };
                t.0.lock().unwrap().error = raw;
                let error = if p2 { ServoError::V2(protocol2::StatusError::from_raw(raw)) } else { ServoError::V1(protocol1::ErrorBits(raw)) };
                let result = bus.read_present(&mut t, 0).map(|p| p.to_vec());
                proptest::prop_assert_eq!(result.is_ok(), !error.is_failure());
                want.note(error);
                proptest::prop_assert_eq!(bus.health()[0], want);
                proptest::prop_assert_eq!(bus.health()[0].alert(protocol), error.alert());
            }
        }
    }

    fn fast_bus(ids: &[u8], choice: ReadChoice) -> JointBus {
        let mut bus = JointBus::new(Protocol::V2, regs2(), ids);
        bus.choose_read(choice, true);
        bus
    }

    #[test]
    fn fast_sync_read_brings_every_position_in_one_reply() {
        let mut t = MemoryTransport::new(true, &[(2, 1000), (1, -5), (3, 7)]);
        let mut bus = fast_bus(&[1, 2, 3], ReadChoice::Fast);
        assert_eq!(bus.read_name(), "fast_sync_read");
        assert_eq!(bus.read_present(&mut t, 0).unwrap(), &[-5, 1000, 7]);
        let mut want = [0u8; 32];
        let n = protocol2::encode_fast_sync_read(&mut want, 132, 4, &[1, 2, 3]).unwrap();
        assert_eq!(t.written(), vec![want[..n].to_vec()]);
        assert_eq!(bus.health()[2].statuses, 1, "each segment's error byte is noted");
        // Noise before the reply (a late byte, line noise) is skipped.
        t.wire().garble_fast = Some(|r| [vec![0xFF, 0x00, 0xFF, 0xFF, 0xFD], r].concat());
        assert_eq!(bus.read_present(&mut t, 0).unwrap(), &[-5, 1000, 7]);
    }

    #[test]
    fn a_servo_missing_from_a_fast_sync_read_takes_the_ones_after_it_with_it() {
        let mut t = MemoryTransport::new(true, &[(1, 10), (2, 20), (3, 30)]);
        let mut bus = fast_bus(&[1, 2, 3], ReadChoice::Fast);
        t.wire().silent = vec![3];
        assert!(matches!(bus.read_present(&mut t, 0), Err(BusError::Timeout { missing: 1 })));
        assert_eq!(bus.answered(), &[true, true, false], "the last one alone");
        t.wire().silent = vec![2];
        assert!(matches!(bus.read_present(&mut t, 0), Err(BusError::Timeout { missing: 2 })));
        assert_eq!(bus.answered(), &[true, false, false], "a cut reply cannot vouch for 3");
        // Left out of the read (a servo known silent), the others answer whole.
        assert!(bus.read_present_of(&mut t, 0, |k| k != 1).is_ok());
        assert_eq!(bus.answered(), &[true, false, true]);
        assert_eq!(bus.present(), &[10, 20, 30]);
    }

    #[test]
    fn a_garbled_fast_sync_read_reply_fails_the_whole_read() {
        let mut t = MemoryTransport::new(true, &[(1, 10), (2, 20)]);
        let mut bus = fast_bus(&[1, 2], ReadChoice::Fast);
        t.wire().garble_fast = Some(|mut r| {
            r[19] ^= 0x40; // the second segment's data
            r
        });
        let error = bus.read_present(&mut t, 0).unwrap_err();
        assert!(matches!(error, BusError::FastSync(FastSyncError::Crc(1))), "{error}");
        assert_eq!(error.read_kind(), BusErrorKind::ReadCorrupt);
        assert_eq!(bus.answered(), &[false, false], "not even the first, whose CRC held");
        // Servo 1 silent and servo 2 answering in its place (the e-manual does not say a
        // follower waits): its ID is not the one listed first, so the whole read fails.
        t.wire().garble_fast = Some(|_| {
            let mut out = protocol2::fast_sync_reply_prefix(2, 4).to_vec();
            let crc = dxl::crc16(&out);
            protocol2::push_fast_sync_segment(&mut out, crc, 2, 0, &20i32.to_le_bytes());
            out
        });
        assert!(matches!(bus.read_present(&mut t, 0), Err(BusError::FastSync(FastSyncError::Id(0)))));
        assert_eq!(bus.answered(), &[false, false]);
        t.wire().garble_fast = None;
        // A segment that reports a failure: that servo refused; the other's position arrives.
        t.wire().silent.clear();
        t.wire().error = 0x07;
        assert!(matches!(bus.read_present(&mut t, 0), Err(BusError::Servo { id: 1, raw: 0x07 })));
        assert_eq!(bus.answered(), &[false, false]);
    }

    #[test]
    fn auto_falls_back_to_sync_read_when_fast_sync_read_goes_unanswered_and_fast_does_not() {
        let mut t = MemoryTransport::new(true, &[(1, 10), (2, 20)]);
        t.wire().no_fast_sync_read = true;
        let mut bus = fast_bus(&[1, 2], ReadChoice::Auto);
        assert_eq!(bus.read_name(), "fast_sync_read");
        bus.settle_read(&mut t, 0).unwrap();
        assert!(bus.fell_back());
        assert_eq!((bus.read_name(), bus.read_present(&mut t, 0).unwrap()), ("sync_read", &[10, 20][..]));
        let mut forced = fast_bus(&[1, 2], ReadChoice::Fast);
        forced.settle_read(&mut t, 0).unwrap();
        assert!(!forced.fell_back() && forced.read_present(&mut t, 0).is_err(), "fast means fast");
        // Where it is answered, auto keeps it; a later failure is a failed read, not a fallback.
        t.wire().no_fast_sync_read = false;
        let mut kept = fast_bus(&[1, 2], ReadChoice::Auto);
        kept.settle_read(&mut t, 0).unwrap();
        t.wire().silent = vec![2];
        assert!(kept.read_present(&mut t, 0).is_err());
        kept.settle_read(&mut t, 0).unwrap();
        assert_eq!((kept.read_name(), kept.fell_back()), ("fast_sync_read", false));
        // Sync, Protocol 1.0, or a model without it: never fast.
        assert_eq!(fast_bus(&[1], ReadChoice::Sync).read_name(), "sync_read");
        let mut p1 = JointBus::new(Protocol::V1, regs1(), &[1]);
        p1.choose_read(ReadChoice::Fast, true);
        assert_eq!(p1.read_name(), "bulk_read");
        let mut unsupported = JointBus::new(Protocol::V2, regs2(), &[1]);
        unsupported.choose_read(ReadChoice::Auto, false);
        assert_eq!(unsupported.read_name(), "sync_read");
    }

    proptest::proptest! {
        /// Whatever arrives for a Fast Sync Read (a flipped byte, a cut, noise): no panic, and a
        /// position is handed on only from a segment the servo really sent.
        #[test]
        fn no_garbled_fast_sync_read_reply_passes_a_wrong_position(
            ticks in proptest::collection::vec(-100_000i64..100_000, 1..12),
            mangle in 0u8..3,
            at in proptest::prelude::any::<proptest::sample::Index>(),
            flip in 1u8..=255,
            noise in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..64),
        ) {
            let ids: Vec<u8> = (1..=ticks.len() as u8).collect();
            let present: Vec<(u8, i64)> = ids.iter().copied().zip(ticks.iter().copied()).collect();
            let mut t = MemoryTransport::new(true, &present);
            let mut bus = fast_bus(&ids, ReadChoice::Fast);
            let good = {
                let mut probe = MemoryTransport::new(true, &present);
                fast_bus(&ids, ReadChoice::Fast).read_present(&mut probe, 0).is_ok()
            };
            proptest::prop_assert!(good);
            let full = protocol2::fast_sync_reply_len(ids.len(), 4);
            let index = at.index(full);
            STATE.with(|s| *s.borrow_mut() = (mangle, index, flip, noise.clone()));
            t.wire().garble_fast = Some(|r| STATE.with(|s| {
                let (mangle, index, flip, noise) = s.borrow().clone();
                match mangle {
                    0 => { let mut r = r; r[index] ^= flip; r }
                    1 => r[..index].to_vec(),
                    _ => noise,
                }
            }));
            let result = bus.read_present_of(&mut t, 0, |_| true);
            for (k, &answered) in bus.answered().iter().enumerate() {
                if answered {
                    proptest::prop_assert_eq!(bus.present()[k], ticks[k]);
                }
            }
            match mangle {
                0 => proptest::prop_assert!(result.is_err() && !bus.answered().contains(&true)),
                1 => proptest::prop_assert_eq!(bus.answered().iter().filter(|a| **a).count(), index.saturating_sub(8) / 8),
                _ => {}
            }
        }
    }

    std::thread_local! {
        static STATE: std::cell::RefCell<(u8, usize, u8, Vec<u8>)> = const { std::cell::RefCell::new((0, 0, 0, Vec::new())) };
    }

    #[test]
    fn a_missing_servo_is_a_timeout_and_torque_off_is_a_broadcast() {
        let mut t = MemoryTransport::new(true, &[(1, 7)]);
        let mut bus = JointBus::new(Protocol::V2, regs2(), &[1, 2]);
        assert!(matches!(bus.read_present(&mut t, 0), Err(BusError::Timeout { missing: 1 })));
        bus.set_torque(&mut t, false).unwrap();
        let last = t.written().pop().unwrap();
        let mut want = [0u8; 32];
        let n = protocol2::encode_sync_write(&mut want, 64, 1, &[1, 2], &[0, 0]).unwrap();
        assert_eq!(last, want[..n].to_vec());
    }
}
