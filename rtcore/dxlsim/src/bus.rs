//! The servos on one bus and how they answer packets: pure logic, no I/O, no clock.
//!
//! `Bus::handle` takes one decoded instruction and returns the status packets the servos
//! send, in bus order, each with the Return Delay Time of the servo that sends it; the server
//! (`server`) turns that into wire timing. Rules, after the e-manual (protocols.md §1.8, §6):
//! - a packet to an absent ID gets no answer; each present ID is answered by its own servo;
//! - broadcast (0xFE) gets answers only for PING (every servo, ascending ID) and Sync/Bulk
//!   Read (the listed servos, in listed order; absent ones are skipped);
//! - Fast Sync Read (0x8A) gets one combined status packet (`dxl::protocol2::fast_sync`):
//!   the first listed servo sends the prefix, each sends its segment after the one before it,
//!   one Return Delay Time (the first servo's) for all. A listed servo that is absent, booting,
//!   at Status Return Level 0 or without the instruction in its firmware sends nothing, and
//!   the ones after it, waiting for its segment, stay silent too: the reply ends there. The
//!   e-manual does not say what later servos do (protocols.md §8); this is the assumption
//!   that costs the client most (every later servo is missing too);
//! - Status Return Level: PING is always answered, READ from level 1, everything else at 2;
//! - bad CRC / checksum: see `Bus::handle_corrupt`;
//! - a booting servo (after REBOOT or a brown-out, `Servo::is_silent`) is off the bus: it
//!   answers nothing and executes nothing, broadcasts and Sync/Bulk records included;
//! - a status packet carries the servo's hardware state as it was when the instruction came
//!   (a REBOOT is answered, with its alert bit, before the servo boots).
use dxl::{protocol1, protocol2, Protocol};

use crate::request::{parse, ParseError, ReadSlot, Request, WriteSlot};
use crate::servo::{Servo, P1_HARDWARE_BITS};
use crate::table::TableError;

pub const BROADCAST_ID: u8 = 0xFE;

/// Why an instruction failed, before it becomes a protocol's error byte. P2's error numbers
/// are the richest vocabulary the two protocols have (P1 folds several into one bit), so the
/// bus speaks them and `error_byte` narrows them for P1.
pub use protocol2::ErrorCode as Fault;

impl From<TableError> for Fault {
    fn from(e: TableError) -> Fault {
        match e {
            TableError::Access => Fault::Access,
            TableError::Length => Fault::DataLength,
            TableError::Range => Fault::DataRange,
            TableError::Limit => Fault::DataLimit,
        }
    }
}

/// One status packet and the Return Delay Time (µs) its servo waits before sending it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reply {
    pub delay_us: u64,
    pub bytes: Vec<u8>,
}

/// Counters of what the bus saw; `stats()` in Python.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    pub packets: u64,
    pub replies: u64,
    pub crc_errors: u64,
    pub unknown_instructions: u64,
    pub malformed: u64,
    pub table_errors: u64,
    pub absent_ids: u64,
    /// Instructions (or Sync/Bulk records) addressed to a servo while it was booting.
    pub silent_drops: u64,
}

/// How much a servo's Status Return Level lets it answer.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Needs {
    Always = 0,
    ReadLevel = 1,
    AllLevel = 2,
}

pub struct Bus {
    protocol: Protocol,
    servos: Vec<Servo>,
    pub counters: Counters,
}

impl Bus {
    /// A bus of servos that all speak `protocol`.
    pub fn new(protocol: Protocol, servos: Vec<Servo>) -> Bus {
        Bus { protocol, servos, counters: Counters::default() }
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    pub fn servos_mut(&mut self) -> &mut [Servo] {
        &mut self.servos
    }

    /// The servo that answers to `id` now.
    pub fn servo(&self, id: u8) -> Option<&Servo> {
        self.servos.iter().find(|s| s.id() == id)
    }

    pub fn servo_mut(&mut self, id: u8) -> Option<&mut Servo> {
        self.servos.iter_mut().find(|s| s.id() == id)
    }

    /// Advances every horn by `h` seconds.
    pub fn step(&mut self, h: f64) {
        self.servos.iter_mut().for_each(|s| s.step(h));
    }

    /// Writes every servo's present values into its table (before answering reads).
    pub fn publish(&mut self) {
        self.servos.iter_mut().for_each(Servo::publish);
    }

    /// Executes one instruction packet; returns the replies in the order they go on the wire.
    pub fn handle(&mut self, id: u8, instruction: u8, params: &[u8]) -> Vec<Reply> {
        self.counters.packets += 1;
        let request = parse(self.protocol, instruction, params);
        let replies = if id == BROADCAST_ID { self.broadcast(request) } else { self.unicast(id, request) };
        self.counters.replies += replies.len() as u64;
        replies
    }

    /// A packet whose CRC (P2) or checksum (P1) is wrong but whose frame is otherwise sound.
    ///
    /// Whether a real servo answers is not documented (protocols.md §8). We answer as its error
    /// codes suggest: the servo the packet names replies with CRC Error (P2 0x03) or the
    /// checksum bit (P1 0x10), if its Status Return Level answers everything (its default);
    /// broadcast and absent IDs stay silent, because several servos answering a corrupt
    /// broadcast at once would collide on a real bus. A client thus sees the cause rather than
    /// a timeout, and a client that ignores the reply just retries.
    pub fn handle_corrupt(&mut self, id: u8) -> Vec<Reply> {
        self.counters.crc_errors += 1;
        if id == BROADCAST_ID {
            return Vec::new();
        }
        let protocol = self.protocol;
        match self.awake(id).map(|k| &self.servos[k]) {
            Some(servo) if servo.status_return_level() >= Needs::AllLevel as i64 => {
                vec![status(protocol, servo, Some(Fault::Crc), &[])]
            }
            _ => Vec::new(),
        }
    }

    /// The index of the servo answering to `id`, unless it is absent or booting (counted).
    fn awake(&mut self, id: u8) -> Option<usize> {
        let Some(index) = self.servos.iter().position(|s| s.id() == id) else {
            self.counters.absent_ids += 1;
            return None;
        };
        if self.servos[index].is_silent() {
            self.counters.silent_drops += 1;
            return None;
        }
        Some(index)
    }

    /// The reply follows the Status Return Level and ID the servo had when the instruction
    /// arrived: a WRITE that changes either is answered as the servo was addressed.
    fn unicast(&mut self, id: u8, request: Result<Request, ParseError>) -> Vec<Reply> {
        let protocol = self.protocol;
        let Some(index) = self.awake(id) else { return Vec::new() };
        let level = self.servos[index].status_return_level();
        let hardware_error = self.servos[index].hardware_error();
        let (outcome, needs) = match request {
            Ok(request) => self.execute(index, request),
            Err(e) => (Err(self.parse_fault(e)), Needs::AllLevel),
        };
        if level < needs as i64 {
            return Vec::new();
        }
        let servo = &self.servos[index];
        let error = |fault| error_byte(protocol, fault, hardware_error);
        let reply = match outcome {
            Ok(data) => encode(protocol, id, error(None), &data, servo.return_delay_us()),
            Err(fault) => encode(protocol, id, error(Some(fault)), &[], servo.return_delay_us()),
        };
        vec![reply]
    }

    fn parse_fault(&mut self, e: ParseError) -> Fault {
        match e {
            ParseError::Unknown => {
                self.counters.unknown_instructions += 1;
                Fault::Instruction
            }
            ParseError::Malformed => {
                self.counters.malformed += 1;
                match self.protocol {
                    Protocol::V2 => Fault::DataLength,
                    Protocol::V1 => Fault::Instruction,
                }
            }
        }
    }

    /// Runs a unicast request on servo `index`: the reply data (or fault) and the Status
    /// Return Level the reply needs.
    fn execute(&mut self, index: usize, request: Request) -> (Result<Vec<u8>, Fault>, Needs) {
        match request {
            Request::Ping => (Ok(ping_data(self.protocol, &self.servos[index])), Needs::Always),
            Request::Read { address, length } => (self.read(index, address, length), Needs::ReadLevel),
            Request::Write { address, data } => (self.write(index, address, &data), Needs::AllLevel),
            Request::RegWrite { address, data } => (self.reg_write(index, address, data), Needs::AllLevel),
            Request::Action => (self.action(index), Needs::AllLevel),
            Request::FactoryReset { option } => (self.factory_reset(index, option), Needs::AllLevel),
            Request::Reboot => {
                self.servos[index].reboot();
                (Ok(Vec::new()), Needs::AllLevel)
            }
            Request::ClearTurns => {
                let cleared = self.servos[index].clear_turns();
                (if cleared { Ok(Vec::new()) } else { Err(Fault::ResultFail) }, Needs::AllLevel)
            }
            // Sync/Bulk instructions are broadcast by definition; to a single ID they are
            // not an instruction a servo accepts.
            Request::MultiRead(_) | Request::FastSyncRead(_) | Request::MultiWrite(_) => (Err(Fault::Instruction), Needs::AllLevel),
        }
    }

    fn broadcast(&mut self, request: Result<Request, ParseError>) -> Vec<Reply> {
        match request {
            Ok(Request::Ping) => self.broadcast_ping(),
            Ok(Request::MultiRead(slots)) => self.multi_read(&slots),
            Ok(Request::FastSyncRead(slots)) => self.fast_sync_read(&slots),
            Ok(Request::MultiWrite(slots)) => {
                self.multi_write(&slots);
                Vec::new()
            }
            Ok(Request::FactoryReset { option: 0xFF }) if self.protocol == Protocol::V2 => Vec::new(),
            Ok(request) => {
                // Every awake servo executes it; none answers a broadcast, errors included.
                for index in 0..self.servos.len() {
                    if !self.servos[index].is_silent() {
                        let _ = self.execute(index, request.clone());
                    }
                }
                Vec::new()
            }
            Err(e) => {
                self.parse_fault(e);
                Vec::new()
            }
        }
    }

    fn broadcast_ping(&self) -> Vec<Reply> {
        let mut order: Vec<&Servo> = self.servos.iter().filter(|s| !s.is_silent()).collect();
        order.sort_by_key(|s| s.id());
        order.into_iter().map(|s| status(self.protocol, s, None, &ping_data(self.protocol, s))).collect()
    }

    fn multi_read(&mut self, slots: &[ReadSlot]) -> Vec<Reply> {
        let mut replies = Vec::new();
        for slot in slots {
            let Some(index) = self.awake(slot.id) else { continue };
            let outcome = self.read(index, slot.address, slot.length);
            let servo = &self.servos[index];
            if servo.status_return_level() < Needs::ReadLevel as i64 {
                continue;
            }
            replies.push(match outcome {
                Ok(data) => status(self.protocol, servo, None, &data),
                Err(fault) => status(self.protocol, servo, Some(fault), &[]),
            });
        }
        replies
    }

    /// One combined reply: the segments of the listed servos up to the first that cannot send
    /// its own (see the module doc), after the first servo's Return Delay Time.
    fn fast_sync_read(&mut self, slots: &[ReadSlot]) -> Vec<Reply> {
        let Some(length) = slots.first().map(|s| usize::from(s.length)) else { return Vec::new() };
        if protocol2::fast_sync_reply_len(slots.len(), length) > protocol2::MAX_PACKET_LEN {
            // Beyond any packet a servo buffers (the SDK's cap too): no servo answers.
            self.counters.malformed += 1;
            return Vec::new();
        }
        let mut bytes = protocol2::fast_sync_reply_prefix(slots.len(), length).to_vec();
        let mut crc = dxl::crc16(&bytes);
        let mut delay_us = None;
        for slot in slots {
            let Some(index) = self.awake(slot.id) else { break };
            let outcome = self.read(index, slot.address, slot.length);
            let servo = &self.servos[index];
            if !servo.spec.fast_sync_read || servo.status_return_level() < Needs::ReadLevel as i64 {
                break;
            }
            delay_us.get_or_insert(servo.return_delay_us());
            let (fault, data) = match outcome {
                Ok(data) => (None, data),
                // The segment keeps its length: the error byte says the data mean nothing.
                Err(fault) => (Some(fault), vec![0; length]),
            };
            let error = error_byte(self.protocol, fault, servo.hardware_error());
            crc = protocol2::push_fast_sync_segment(&mut bytes, crc, slot.id, error, &data);
        }
        match delay_us {
            Some(delay_us) => vec![Reply { delay_us, bytes }],
            None => Vec::new(),
        }
    }

    fn multi_write(&mut self, slots: &[WriteSlot]) {
        for slot in slots {
            if let Some(index) = self.awake(slot.id) {
                let _ = self.write(index, slot.address, &slot.data);
            }
        }
    }

    fn read(&mut self, index: usize, address: u16, length: u16) -> Result<Vec<u8>, Fault> {
        let result = self.servos[index].read_table(address, length);
        self.count(result.map_err(Fault::from))
    }

    fn write(&mut self, index: usize, address: u16, data: &[u8]) -> Result<Vec<u8>, Fault> {
        let result = self.servos[index].write(address, data).map(|()| Vec::new());
        self.count(result.map_err(Fault::from))
    }

    /// REG_WRITE stores the write for ACTION, after checking it would be accepted now.
    fn reg_write(&mut self, index: usize, address: u16, data: Vec<u8>) -> Result<Vec<u8>, Fault> {
        let servo = &mut self.servos[index];
        let result = servo.check_write(address, &data).map(|()| Vec::new()).map_err(Fault::from);
        if result.is_ok() {
            servo.registered = Some((address, data));
        }
        self.count(result)
    }

    fn action(&mut self, index: usize) -> Result<Vec<u8>, Fault> {
        match self.servos[index].registered.take() {
            Some((address, data)) => self.write(index, address, &data),
            None => Err(Fault::Instruction),
        }
    }

    /// FACTORY_RESET: 0xFF resets everything, 0x01 keeps the ID, 0x02 keeps ID and baud rate
    /// (P1 has no option and resets everything).
    fn factory_reset(&mut self, index: usize, option: u8) -> Result<Vec<u8>, Fault> {
        let servo = &mut self.servos[index];
        let (id, baud) = (servo.table.get("ID"), servo.table.get("Baud Rate"));
        servo.table.reset_to_defaults();
        let keep_id = servo.protocol() == Protocol::V2 && matches!(option, 0x01 | 0x02);
        if let (true, Some(id)) = (keep_id, id) {
            servo.table.set_checked("ID", id).map_err(Fault::from)?;
        }
        if let (true, Some(baud)) = (option == 0x02, baud) {
            servo.table.set_checked("Baud Rate", baud).map_err(Fault::from)?;
        }
        servo.publish();
        Ok(Vec::new())
    }

    fn count(&mut self, result: Result<Vec<u8>, Fault>) -> Result<Vec<u8>, Fault> {
        if result.is_err() {
            self.counters.table_errors += 1;
        }
        result
    }
}

/// PING's data: P2 model number and firmware version; P1 none.
fn ping_data(protocol: Protocol, servo: &Servo) -> Vec<u8> {
    match protocol {
        Protocol::V2 => {
            let model = servo.model_number().to_le_bytes();
            vec![model[0], model[1], servo.firmware_version()]
        }
        Protocol::V1 => Vec::new(),
    }
}

/// The protocol's error byte for a fault plus the servo's hardware state.
pub fn error_byte(protocol: Protocol, fault: Option<Fault>, hardware_error: u8) -> u8 {
    match protocol {
        Protocol::V2 => protocol2::StatusError { alert: hardware_error != 0, code: fault }.raw(),
        Protocol::V1 => {
            let bit = match fault {
                None => 0,
                Some(Fault::Instruction) => protocol1::ErrorBits::INSTRUCTION,
                Some(Fault::Crc) => protocol1::ErrorBits::CHECKSUM,
                Some(Fault::DataLimit) => protocol1::ErrorBits::ANGLE_LIMIT,
                // P1 has one bit for every refused value or address: Range.
                Some(Fault::DataRange | Fault::DataLength | Fault::Access | Fault::ResultFail | Fault::Other(_)) => {
                    protocol1::ErrorBits::RANGE
                }
            };
            bit | (hardware_error & P1_HARDWARE_BITS)
        }
    }
}

fn status(protocol: Protocol, servo: &Servo, fault: Option<Fault>, data: &[u8]) -> Reply {
    let error = error_byte(protocol, fault, servo.hardware_error());
    encode(protocol, servo.id(), error, data, servo.return_delay_us())
}

fn encode(protocol: Protocol, id: u8, error: u8, data: &[u8], delay_us: u64) -> Reply {
    // A status packet is at most 1.5× its data (P2 stuffing) plus framing.
    let mut buf = vec![0u8; 16 + data.len() * 3 / 2];
    let written = match protocol {
        Protocol::V2 => protocol2::encode_status(&mut buf, id, error, data),
        Protocol::V1 => protocol1::encode_status(&mut buf, id, error, data),
    };
    // Encoding fails only for an ID the protocol forbids or data beyond the length field; the
    // table never yields either (IDs are range-checked, reads are bounded by the table size),
    // so an empty reply (silence) is the safe fallback.
    buf.truncate(written.unwrap_or(0));
    Reply { delay_us, bytes: buf }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::setup::{build_bus, ServoConfig};
    use dxl::instruction as ins;
    use dxl::Kind;
    use plant::Params;

    fn bus(protocol: Protocol, ids: &[u8]) -> Bus {
        let params = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..Params::default() };
        let configs = ids.iter().map(|&id| ServoConfig { protocol, ..ServoConfig::new(id, params) }).collect();
        build_bus(configs, 1_000_000).unwrap()
    }

    /// Decodes P2 status packets: (id, error, data) each.
    fn statuses(replies: &[Reply]) -> Vec<(u8, u8, Vec<u8>)> {
        let mut decoder = protocol2::Decoder::new();
        let mut out = Vec::new();
        for reply in replies {
            decoder.push(&reply.bytes);
            while let Some(Ok(p)) = decoder.next() {
                let Kind::Status(e) = p.kind else { panic!("not a status") };
                out.push((p.id, e.raw(), p.params.to_vec()));
            }
        }
        out
    }

    #[test]
    fn ping_answers_model_and_firmware_with_the_return_delay() {
        let mut b = bus(Protocol::V2, &[1]);
        let replies = b.handle(1, ins::PING, &[]);
        assert_eq!(replies[0].delay_us, 500);
        let (id, error, data) = statuses(&replies).remove(0);
        assert_eq!((id, error), (1, 0));
        assert_eq!(u16::from_le_bytes([data[0], data[1]]), 311);
    }

    #[test]
    fn absent_ids_are_silent_and_counted() {
        let mut b = bus(Protocol::V2, &[1]);
        assert!(b.handle(9, ins::PING, &[]).is_empty());
        assert_eq!(b.counters.absent_ids, 1);
    }

    #[test]
    fn broadcast_ping_answers_in_id_order() {
        let mut b = bus(Protocol::V2, &[7, 2, 4]);
        let ids: Vec<u8> = statuses(&b.handle(BROADCAST_ID, ins::PING, &[])).iter().map(|s| s.0).collect();
        assert_eq!(ids, [2, 4, 7]);
    }

    #[test]
    fn sync_read_answers_in_listed_order_and_skips_absent_ids() {
        let mut b = bus(Protocol::V2, &[1, 2, 3]);
        let replies = b.handle(BROADCAST_ID, ins::SYNC_READ, &[0, 0, 2, 0, 3, 9, 1]);
        let got: Vec<(u8, Vec<u8>)> = statuses(&replies).into_iter().map(|(id, _, d)| (id, d)).collect();
        assert_eq!(got, [(3, vec![0x37, 0x01]), (1, vec![0x37, 0x01])]);
    }

    /// The segments of a Fast Sync Read reply: (id, error, data) each, the whole reply checked.
    fn fast_segments(replies: &[Reply], ids: &[u8], x: usize) -> Vec<(u8, u8, Vec<u8>)> {
        let mut out = Vec::new();
        let bytes = &replies[0].bytes;
        let whole = protocol2::decode_fast_sync_prefix(bytes, ids, x, |k, e, d| out.push((ids[k], e, d.to_vec()))).unwrap();
        assert_eq!(bytes.len(), 8 + whole * (4 + x), "no byte beyond the last whole segment");
        out
    }

    #[test]
    fn fast_sync_read_is_one_reply_with_one_return_delay() {
        let mut b = bus(Protocol::V2, &[1, 2, 3]);
        b.handle(2, ins::WRITE, &[9, 0, 10]); // ID 2's Return Delay Time 20 µs; the first's counts
        let replies = b.handle(BROADCAST_ID, ins::FAST_SYNC_READ, &[0, 0, 2, 0, 3, 1, 2]);
        assert_eq!(replies.len(), 1);
        assert_eq!(replies[0].delay_us, 500, "the first listed servo's");
        assert_eq!(replies[0].bytes.len(), protocol2::fast_sync_reply_len(3, 2));
        let got = fast_segments(&replies, &[3, 1, 2], 2);
        assert_eq!(got, [(3, 0, vec![0x37, 0x01]), (1, 0, vec![0x37, 0x01]), (2, 0, vec![0x37, 0x01])]);
        assert!(b.handle(1, ins::FAST_SYNC_READ, &[0, 0, 2, 0, 1])[0].bytes.len() == 11, "to one ID: an Instruction Error status");
    }

    #[test]
    fn a_fast_sync_read_reply_ends_at_the_first_servo_that_cannot_send() {
        let mut b = bus(Protocol::V2, &[1, 2, 3]);
        let ask = |b: &mut Bus, ids: &[u8]| {
            let params: Vec<u8> = [132, 0, 4, 0].into_iter().chain(ids.iter().copied()).collect();
            b.handle(BROADCAST_ID, ins::FAST_SYNC_READ, &params)
        };
        let ids_of = |r: &[Reply], ids: &[u8]| fast_segments(r, ids, 4).iter().map(|s| s.0).collect::<Vec<u8>>();
        assert_eq!(ids_of(&ask(&mut b, &[1, 9, 2]), &[1, 9, 2]), [1], "an absent ID cuts the reply");
        b.servo_mut(2).unwrap().brown_out(0.2);
        assert_eq!(ids_of(&ask(&mut b, &[1, 3, 2]), &[1, 3, 2]), [1, 3], "a booting servo");
        assert!(ask(&mut b, &[2, 1]).is_empty(), "the first silent: nothing at all");
        b.servo_mut(3).unwrap().spec.fast_sync_read = false;
        assert!(ask(&mut b, &[3, 1]).is_empty(), "a firmware without it ignores it");
        let mut p1 = bus(Protocol::V1, &[1]);
        assert!(p1.handle(BROADCAST_ID, ins::FAST_SYNC_READ, &[36, 2, 1]).is_empty());
        assert_eq!(p1.counters.unknown_instructions, 1);
    }

    #[test]
    fn a_refused_fast_sync_read_segment_keeps_its_length_and_says_why() {
        let mut b = bus(Protocol::V2, &[1, 2]);
        let replies = b.handle(BROADCAST_ID, ins::FAST_SYNC_READ, &[0xF0, 0x0F, 4, 0, 1, 2]);
        let got = fast_segments(&replies, &[1, 2], 4);
        assert_eq!(got, [(1, 0x07, vec![0; 4]), (2, 0x07, vec![0; 4])], "Access Error, data zeroed");
        assert!(b.handle(BROADCAST_ID, ins::FAST_SYNC_READ, &[0, 0, 0xFF, 0x7F, 1, 2]).is_empty(), "beyond any packet");
    }

    #[test]
    fn sync_write_changes_every_listed_servo_silently() {
        let mut b = bus(Protocol::V2, &[1, 2]);
        let params = [116, 0, 4, 0, 1, 0x10, 0, 0, 0, 2, 0x20, 0, 0, 0];
        assert!(b.handle(BROADCAST_ID, ins::SYNC_WRITE, &params).is_empty());
        assert_eq!(b.servo(1).unwrap().table.get("Goal Position"), Some(0x10));
        assert_eq!(b.servo(2).unwrap().table.get("Goal Position"), Some(0x20));
    }

    #[test]
    fn errors_are_e_manual_numbers_on_p2_and_bits_on_p1() {
        let mut b = bus(Protocol::V2, &[1]);
        let error = |b: &mut Bus, code, params: &[u8]| statuses(&b.handle(1, code, params))[0].1;
        assert_eq!(error(&mut b, ins::READ, &[14, 0, 1, 0]), 0x07);
        assert_eq!(error(&mut b, ins::WRITE, &[64, 0, 5]), 0x04);
        assert_eq!(error(&mut b, 0x77, &[]), 0x02);
        assert_eq!(error(&mut b, ins::READ, &[14]), 0x05);
        // Goal Position 5000 exceeds Max Position Limit (4095) in position mode only.
        assert_eq!(error(&mut b, ins::WRITE, &[116, 0, 0x88, 0x13, 0, 0]), 0x06);
        assert_eq!(error(&mut b, ins::WRITE, &[11, 0, 4]), 0x00);
        assert_eq!(error(&mut b, ins::WRITE, &[116, 0, 0x88, 0x13, 0, 0]), 0x00);
        let mut p1 = bus(Protocol::V1, &[1]);
        let replies = p1.handle(1, ins::WRITE, &[36, 0, 0]);
        let mut decoder = protocol1::Decoder::new(protocol1::Expect::Status);
        decoder.push(&replies[0].bytes);
        let Some(Ok(p)) = decoder.next() else { panic!("no P1 status") };
        assert_eq!(p.kind, Kind::Status(dxl::ServoError::V1(protocol1::ErrorBits(0x08))));
    }

    /// Steps the physics by `seconds` (the clock a booting servo waits on).
    fn run(b: &mut Bus, seconds: f64) {
        for _ in 0..(seconds / 5e-4).round() as usize {
            b.step(5e-4);
        }
    }

    #[test]
    fn hardware_errors_set_the_alert_bit_until_a_reboot_which_is_answered_then_silent() {
        let mut b = bus(Protocol::V2, &[1]);
        b.servo_mut(1).unwrap().set_hardware_error(0x04);
        assert_eq!(statuses(&b.handle(1, ins::PING, &[]))[0].1, 0x80);
        assert_eq!(statuses(&b.handle(1, ins::REBOOT, &[]))[0].1, 0x80, "answered as it was, before booting");
        assert!(b.handle(1, ins::PING, &[]).is_empty(), "silent while it boots");
        assert_eq!(b.counters.silent_drops, 1);
        run(&mut b, 0.41);
        assert_eq!(statuses(&b.handle(1, ins::PING, &[]))[0].1, 0x00);
    }

    #[test]
    fn a_shutdown_keeps_torque_off_until_a_reboot() {
        let mut b = bus(Protocol::V2, &[1]);
        b.handle(1, ins::WRITE, &[64, 0, 1]);
        b.servo_mut(1).unwrap().set_hardware_error(0x20);
        let torque = |b: &mut Bus| statuses(&b.handle(1, ins::READ, &[64, 0, 1, 0]))[0].clone();
        assert_eq!(torque(&mut b), (1, 0x80, vec![0]), "overload is in the default Shutdown mask");
        assert_eq!(statuses(&b.handle(1, ins::WRITE, &[64, 0, 1]))[0].1, 0x80);
        assert_eq!(torque(&mut b).2, vec![0], "Torque Enable = 1 is undone while the error stands");
        assert_eq!(statuses(&b.handle(1, ins::READ, &[70, 0, 1, 0]))[0].2, vec![0x20]);
        b.handle(1, ins::REBOOT, &[]);
        run(&mut b, 0.41);
        b.handle(1, ins::WRITE, &[64, 0, 1]);
        assert_eq!(torque(&mut b), (1, 0x00, vec![1]));
    }

    #[test]
    fn p1_status_carries_the_hardware_bits_and_alarm_shutdown_turns_torque_off() {
        let mut b = bus(Protocol::V1, &[1]);
        b.handle(1, ins::WRITE, &[24, 1]);
        b.servo_mut(1).unwrap().set_hardware_error(0x20);
        let replies = b.handle(1, ins::READ, &[24, 1]);
        let mut decoder = protocol1::Decoder::new(protocol1::Expect::Status);
        decoder.push(&replies[0].bytes);
        let Some(Ok(p)) = decoder.next() else { panic!("no P1 status") };
        assert_eq!((p.kind, p.params), (Kind::Status(dxl::ServoError::V1(protocol1::ErrorBits(0x20))), &[0u8][..]));
        // Electrical shock and encoder have no P1 bit.
        b.servo_mut(1).unwrap().set_hardware_error(0x18);
        assert_eq!(b.handle(1, ins::PING, &[])[0].bytes[4], 0x00);
    }

    #[test]
    fn a_brown_out_resets_ram_and_silences_the_servo_for_a_while() {
        let mut b = bus(Protocol::V2, &[1, 2]);
        b.handle(1, ins::WRITE, &[9, 0, 0]); // Return Delay Time is EEPROM: it survives
        b.handle(1, ins::WRITE, &[64, 0, 1]);
        b.handle(1, ins::WRITE, &[65, 0, 1]); // LED is RAM: it does not
        b.servo_mut(1).unwrap().brown_out(0.2);
        assert!(b.handle(1, ins::READ, &[64, 0, 1, 0]).is_empty());
        let sync = b.handle(BROADCAST_ID, ins::SYNC_READ, &[64, 0, 1, 0, 1, 2]);
        assert_eq!(statuses(&sync).iter().map(|s| s.0).collect::<Vec<_>>(), [2], "the booting servo is skipped");
        b.handle(BROADCAST_ID, ins::SYNC_WRITE, &[65, 0, 1, 0, 1, 1]);
        run(&mut b, 0.21);
        let servo = b.servo(1).unwrap();
        assert_eq!((servo.table.get("Torque Enable"), servo.table.get("LED"), servo.table.get("Return Delay Time")), (Some(0), Some(0), Some(0)));
        assert_eq!(statuses(&b.handle(1, ins::PING, &[]))[0].1, 0);
    }

    #[test]
    fn torque_found_off_has_no_error_bit() {
        let mut b = bus(Protocol::V2, &[1]);
        b.handle(1, ins::WRITE, &[64, 0, 1]);
        b.servo_mut(1).unwrap().torque_off();
        assert_eq!(statuses(&b.handle(1, ins::READ, &[64, 0, 1, 0]))[0], (1, 0x00, vec![0]));
    }

    #[test]
    fn clear_needs_its_magic_parameters() {
        let mut b = bus(Protocol::V2, &[1]);
        assert_eq!(statuses(&b.handle(1, ins::CLEAR, &[0x01, 0x44, 0x58, 0x4C, 0x22]))[0].1, 0x00);
        assert_eq!(statuses(&b.handle(1, ins::CLEAR, &[0x01, 0x00]))[0].1, 0x05);
        let mut p1 = bus(Protocol::V1, &[1]);
        assert_eq!(p1.handle(1, ins::CLEAR, &[0x01, 0x44, 0x58, 0x4C, 0x22])[0].bytes[4], 0x40);
    }

    #[test]
    fn status_return_level_one_answers_reads_only() {
        let mut b = bus(Protocol::V2, &[1]);
        b.servo_mut(1).unwrap().table.set_checked("Status Return Level", 1).unwrap();
        assert!(b.handle(1, ins::WRITE, &[65, 0, 1]).is_empty());
        assert_eq!(statuses(&b.handle(1, ins::READ, &[65, 0, 1, 0]))[0].2, [1]);
    }

    #[test]
    fn reg_write_waits_for_action() {
        let mut b = bus(Protocol::V2, &[1]);
        b.handle(1, ins::REG_WRITE, &[65, 0, 1]);
        assert_eq!(b.servo(1).unwrap().table.get("LED"), Some(0));
        b.handle(BROADCAST_ID, ins::ACTION, &[]);
        assert_eq!(b.servo(1).unwrap().table.get("LED"), Some(1));
        assert_eq!(statuses(&b.handle(1, ins::ACTION, &[]))[0].1, 0x02, "ACTION without REG_WRITE");
    }

    #[test]
    fn corrupt_packets_answer_crc_error_only_to_present_ids() {
        let mut b = bus(Protocol::V2, &[1]);
        assert_eq!(statuses(&b.handle_corrupt(1))[0].1, 0x03);
        assert!(b.handle_corrupt(5).is_empty());
        assert!(b.handle_corrupt(BROADCAST_ID).is_empty());
        assert_eq!(b.counters.crc_errors, 3);
    }

    proptest::proptest! {
        #[test]
        fn any_instruction_leaves_well_formed_replies(
            id in proptest::prop_oneof![0u8..4, proptest::strategy::Just(BROADCAST_ID)],
            instruction in proptest::prop_oneof![proptest::strategy::Just(ins::WRITE), proptest::prelude::any::<u8>()],
            address in 0u8..150,
            data in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..40),
        ) {
            let mut b = bus(Protocol::V2, &[1, 2]);
            let params: Vec<u8> = [address, 0].into_iter().chain(data).collect();
            let replies = b.handle(id, instruction, &params);
            let decoded = statuses(&replies);
            proptest::prop_assert_eq!(decoded.len(), replies.len());
            // Whatever the instruction wrote, the physics stays finite.
            for _ in 0..100 {
                b.step(5e-4);
            }
            let finite = b.servos_mut().iter().all(|s| s.snapshot().theta.is_finite() && s.snapshot().omega.is_finite());
            proptest::prop_assert!(finite);
        }
    }

    #[test]
    fn factory_reset_keeps_the_id_when_asked() {
        let mut b = bus(Protocol::V2, &[5]);
        b.handle(5, ins::WRITE, &[9, 0, 0]);
        b.handle(5, ins::FACTORY_RESET, &[0x01]);
        let servo = b.servo(5).unwrap();
        assert_eq!(servo.table.get("Return Delay Time"), Some(250));
        assert!(b.handle(BROADCAST_ID, ins::FACTORY_RESET, &[0xFF]).is_empty());
        assert!(b.servo(5).is_some(), "a broadcast reset-all is not executed");
    }
}
