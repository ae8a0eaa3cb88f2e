//! The servos on one bus and how they answer packets: pure logic, no I/O, no clock.
//!
//! `Bus::handle` takes one decoded instruction and returns the status packets the servos
//! send, in bus order, each with the Return Delay Time of the servo that sends it; the server
//! (`server`) turns that into wire timing. Rules, after the e-manual (protocols.md §1.8, §6):
//! - a packet to an absent ID gets no answer; each present ID is answered by its own servo;
//! - broadcast (0xFE) gets answers only for PING (every servo, ascending ID) and Sync/Bulk
//!   Read (the listed servos, in listed order; absent ones are skipped);
//! - Status Return Level: PING is always answered, READ from level 1, everything else at 2;
//! - bad CRC / checksum: see `Bus::handle_corrupt`.
use dxl::{protocol1, protocol2, Protocol};

use crate::request::{parse, ParseError, ReadSlot, Request, WriteSlot};
use crate::servo::{Servo, P1_HARDWARE_BITS};
use crate::table::TableError;

pub const BROADCAST_ID: u8 = 0xFE;

/// Why an instruction failed, before it becomes a protocol's error byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    Instruction,
    Crc,
    DataRange,
    DataLength,
    Access,
}

impl From<TableError> for Fault {
    fn from(e: TableError) -> Fault {
        match e {
            TableError::Access => Fault::Access,
            TableError::Length => Fault::DataLength,
            TableError::Range => Fault::DataRange,
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
        let protocol = self.protocol;
        match self.servo(id) {
            Some(servo) if servo.status_return_level() >= Needs::AllLevel as i64 => {
                vec![status(protocol, servo, Some(Fault::Crc), &[])]
            }
            Some(_) => Vec::new(),
            None => {
                self.counters.absent_ids += 1;
                Vec::new()
            }
        }
    }

    fn unicast(&mut self, id: u8, request: Result<Request, ParseError>) -> Vec<Reply> {
        let protocol = self.protocol;
        let Some(index) = self.servos.iter().position(|s| s.id() == id) else {
            self.counters.absent_ids += 1;
            return Vec::new();
        };
        let (outcome, needs) = match request {
            Ok(request) => self.execute(index, request),
            Err(e) => (Err(self.parse_fault(e)), Needs::AllLevel),
        };
        let servo = &self.servos[index];
        if servo.status_return_level() < needs as i64 {
            return Vec::new();
        }
        match outcome {
            Ok(data) => vec![status(protocol, servo, None, &data)],
            Err(fault) => vec![status(protocol, servo, Some(fault), &[])],
        }
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
            // Sync/Bulk instructions are broadcast by definition; to a single ID they are
            // not an instruction a servo accepts.
            Request::MultiRead(_) | Request::MultiWrite(_) => (Err(Fault::Instruction), Needs::AllLevel),
        }
    }

    fn broadcast(&mut self, request: Result<Request, ParseError>) -> Vec<Reply> {
        match request {
            Ok(Request::Ping) => self.broadcast_ping(),
            Ok(Request::MultiRead(slots)) => self.multi_read(&slots),
            Ok(Request::MultiWrite(slots)) => {
                self.multi_write(&slots);
                Vec::new()
            }
            Ok(Request::FactoryReset { option: 0xFF }) if self.protocol == Protocol::V2 => Vec::new(),
            Ok(request) => {
                // Every servo executes it; none answers a broadcast, errors included.
                for index in 0..self.servos.len() {
                    let _ = self.execute(index, request.clone());
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
        let mut order: Vec<&Servo> = self.servos.iter().collect();
        order.sort_by_key(|s| s.id());
        order.into_iter().map(|s| status(self.protocol, s, None, &ping_data(self.protocol, s))).collect()
    }

    fn multi_read(&mut self, slots: &[ReadSlot]) -> Vec<Reply> {
        let mut replies = Vec::new();
        for slot in slots {
            let Some(index) = self.servos.iter().position(|s| s.id() == slot.id) else {
                self.counters.absent_ids += 1;
                continue;
            };
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

    fn multi_write(&mut self, slots: &[WriteSlot]) {
        for slot in slots {
            match self.servos.iter().position(|s| s.id() == slot.id) {
                Some(index) => {
                    let _ = self.write(index, slot.address, &slot.data);
                }
                None => self.counters.absent_ids += 1,
            }
        }
    }

    fn read(&mut self, index: usize, address: u16, length: u16) -> Result<Vec<u8>, Fault> {
        let result = self.servos[index].table.read(address, length).map(<[u8]>::to_vec);
        self.count(result.map_err(Fault::from))
    }

    fn write(&mut self, index: usize, address: u16, data: &[u8]) -> Result<Vec<u8>, Fault> {
        let result = self.servos[index].write(address, data).map(|()| Vec::new());
        self.count(result.map_err(Fault::from))
    }

    /// REG_WRITE stores the write for ACTION, after checking it would be accepted now.
    fn reg_write(&mut self, index: usize, address: u16, data: Vec<u8>) -> Result<Vec<u8>, Fault> {
        let servo = &mut self.servos[index];
        let mut probe = servo.table.clone();
        let locked = servo.protocol() == Protocol::V2 && servo.snapshot().torque_enabled;
        let result = probe.write(address, &data, locked).map(|()| Vec::new()).map_err(Fault::from);
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
        Protocol::V2 => {
            let code = match fault {
                None => 0,
                Some(Fault::Instruction) => 0x02,
                Some(Fault::Crc) => 0x03,
                Some(Fault::DataRange) => 0x04,
                Some(Fault::DataLength) => 0x05,
                Some(Fault::Access) => 0x07,
            };
            code | if hardware_error != 0 { 0x80 } else { 0 }
        }
        Protocol::V1 => {
            let bit = match fault {
                None => 0,
                Some(Fault::Instruction) => protocol1::ErrorBits::INSTRUCTION,
                Some(Fault::Crc) => protocol1::ErrorBits::CHECKSUM,
                // P1 has one bit for every refused value or address: Range.
                Some(Fault::DataRange | Fault::DataLength | Fault::Access) => protocol1::ErrorBits::RANGE,
            };
            bit | (hardware_error & P1_HARDWARE_BITS)
        }
    }
}

fn status(protocol: Protocol, servo: &Servo, fault: Option<Fault>, data: &[u8]) -> Reply {
    let error = error_byte(protocol, fault, servo.hardware_error());
    let id = servo.id();
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
    Reply { delay_us: servo.return_delay_us(), bytes: buf }
}
