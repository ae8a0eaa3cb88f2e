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
//! Present positions: Protocol 2.0 uses SYNC_READ; Protocol 1.0 has none, so it uses BULK_READ
//! (which the MX series supports). Replies arrive in request order within one deadline.
use dxl::{protocol1, protocol2, AnyDecoder, BulkEntry, DecodeError, EncodeError, Kind, Packet, Protocol};
use std::fmt;
use std::io;

/// Bytes out, bytes in with a deadline on CLOCK_MONOTONIC.
pub trait Transport: Send {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what is available; if nothing is, waits until `deadline_ns` at most. `Ok(0)` means
    /// the deadline passed with nothing to read.
    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> io::Result<usize>;
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
}

impl fmt::Display for BusError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BusError::Io(e) => write!(f, "serial I/O failed: {e}"),
            BusError::Encode(e) => write!(f, "cannot encode the packet: {e}"),
            BusError::Decode(e) => write!(f, "bad reply: {e}"),
            BusError::Timeout { missing } => write!(f, "{missing} servo(s) did not answer in time"),
            BusError::Servo { id, raw } => write!(f, "servo {id} reported error 0x{raw:02X}"),
        }
    }
}

impl std::error::Error for BusError {}

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
        }
    }

    pub fn ids(&self) -> &[u8] {
        &self.ids
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
        self.discard_input(t)?;
        let n = match self.protocol {
            Protocol::V1 => protocol1::encode_bulk_read(&mut self.packet, &self.entries),
            Protocol::V2 => protocol2::encode_sync_read(
                &mut self.packet,
                self.regs.present_address,
                self.regs.present_size,
                &self.ids,
            ),
        }
        .map_err(BusError::Encode)?;
        t.write_all(&self.packet[..n]).map_err(BusError::Io)?;
        self.answered.fill(false);
        let mut pending = self.ids.len();
        let mut first_error = None;
        while pending > 0 {
            let got = t.read_until(&mut self.rx, deadline_ns).map_err(BusError::Io)?;
            if got == 0 {
                return Err(first_error.unwrap_or(BusError::Timeout { missing: pending }));
            }
            self.decoder.push(&self.rx[..got]);
            while let Some(item) = self.decoder.next() {
                match accept(item, &self.ids, usize::from(self.regs.present_size)) {
                    Ok(Some((k, tick))) if !self.answered[k] => {
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
            None => Ok(&self.present),
        }
    }

    /// Drops bytes left over from an earlier, late reply so they cannot pass for this one.
    fn discard_input(&mut self, t: &mut dyn Transport) -> Result<(), BusError> {
        self.decoder.clear();
        while t.read_until(&mut self.rx, 0).map_err(BusError::Io)? > 0 {}
        Ok(())
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
    if packet.params.len() < size {
        return Ok(None);
    }
    Ok(Some((k, get_le(&packet.params[..size]))))
}

#[cfg(test)]
pub(crate) mod memory {
    //! An in-memory bus for the tests: records every packet written and answers reads of the
    //! present position from a table, like servos would.
    use super::*;
    use std::collections::VecDeque;
    use std::sync::{Arc, Mutex};

    #[derive(Default)]
    pub struct Wire {
        pub written: Vec<Vec<u8>>,
        pub present: Vec<(u8, i64)>,
        pub replies: VecDeque<u8>,
        pub fail_writes: bool,
        pub protocol2: bool,
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
    }

    fn reply(wire: &mut Wire, request: &[u8]) {
        let instruction = if wire.protocol2 { request[7] } else { request[4] };
        if instruction != 0x82 && instruction != 0x92 {
            return;
        }
        let mut buf = [0u8; 64];
        for (id, tick) in wire.present.clone() {
            let n = if wire.protocol2 {
                protocol2::encode_status(&mut buf, id, 0, &(tick as i32).to_le_bytes()).unwrap()
            } else {
                protocol1::encode_status(&mut buf, id, 0, &(tick as u16).to_le_bytes()).unwrap()
            };
            wire.replies.extend(&buf[..n]);
        }
    }

    impl Transport for MemoryTransport {
        fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
            let mut wire = self.0.lock().unwrap();
            if wire.fail_writes {
                return Err(io::Error::new(io::ErrorKind::BrokenPipe, "unplugged"));
            }
            wire.written.push(bytes.to_vec());
            reply(&mut wire, bytes);
            Ok(())
        }
        fn read_until(&mut self, buf: &mut [u8], _deadline_ns: u64) -> io::Result<usize> {
            let mut wire = self.0.lock().unwrap();
            let n = buf.len().min(wire.replies.len());
            for b in buf.iter_mut().take(n) {
                *b = wire.replies.pop_front().unwrap();
            }
            Ok(n)
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
