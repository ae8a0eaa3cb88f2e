//! The streaming P2 decoder: push bytes as they arrive, pop whole packets (instruction or
//! status) or typed framing errors. Garbage before a header is skipped and counted; after a
//! bad length or CRC only the first header byte is dropped, so a real packet hidden inside
//! the bad candidate is still found. No input makes it panic or allocate.
use super::stuffing::unstuff;
use super::{MAX_PACKET_LEN, PREFIX_LEN};
use crate::crc::crc16;
use crate::instruction::STATUS;
use crate::packet::{DecodeError, Kind, Packet, ServoError};
use crate::protocol2::StatusError;
use crate::stream::ByteStream;

/// The header the decoder looks for: `FF FF FD 00` (a stuffed `FF FF FD FD` never matches).
const SYNC: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];

pub struct Decoder {
    stream: ByteStream,
    body: Box<[u8]>,
    max_packet: usize,
    crc_errors: u64,
}

/// What the framing step found, before the body is unstuffed into `Decoder::body`.
enum Framed {
    NeedMore,
    Error(DecodeError),
    Packet { id: u8, total: usize },
}

impl Default for Decoder {
    fn default() -> Self {
        Decoder::new()
    }
}

impl Decoder {
    /// A decoder for packets up to the SDK's 1024-byte cap.
    pub fn new() -> Decoder {
        Decoder::with_max_packet(MAX_PACKET_LEN)
    }

    /// A decoder for packets up to `max_packet` bytes (at least the 10-byte PING).
    pub fn with_max_packet(max_packet: usize) -> Decoder {
        let max_packet = max_packet.clamp(PREFIX_LEN + 3, PREFIX_LEN + u16::MAX as usize);
        Decoder {
            stream: ByteStream::with_capacity(2 * max_packet),
            body: vec![0; max_packet].into_boxed_slice(),
            max_packet,
            crc_errors: 0,
        }
    }

    /// Buffer bytes; returns how many fit. Call `next` until `None` before pushing the rest.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        self.stream.push(bytes)
    }

    /// Bytes dropped as garbage so far (outside any packet, or in rejected candidates).
    pub fn skipped_bytes(&self) -> u64 {
        self.stream.skipped()
    }

    pub fn crc_errors(&self) -> u64 {
        self.crc_errors
    }

    /// Bytes buffered but not yet decoded.
    pub fn buffered(&self) -> usize {
        self.stream.pending().len()
    }

    pub fn capacity(&self) -> usize {
        self.stream.capacity()
    }

    /// Forget buffered bytes (e.g. before a new request); the counters stay.
    pub fn clear(&mut self) {
        self.stream.clear();
    }

    /// The next packet or framing error, or `None` when more bytes are needed.
    #[allow(clippy::should_implement_trait)] // a lending iterator: packets borrow the decoder
    pub fn next(&mut self) -> Option<Result<Packet<'_>, DecodeError>> {
        match self.frame() {
            Framed::NeedMore => None,
            Framed::Error(e) => Some(Err(e)),
            Framed::Packet { id, total } => Some(Ok(self.take(id, total))),
        }
    }

    fn frame(&mut self) -> Framed {
        loop {
            if !self.stream.seek_header(&SYNC) {
                return Framed::NeedMore;
            }
            let data = self.stream.pending();
            if data.len() < PREFIX_LEN + 1 {
                return Framed::NeedMore;
            }
            let id = data[4];
            if id == 0xFD || id == 0xFF {
                self.stream.skip(1);
                continue;
            }
            let length = usize::from(u16::from_le_bytes([data[5], data[6]]));
            let minimum = if data[7] == STATUS { 4 } else { 3 };
            let maximum = self.max_packet - PREFIX_LEN;
            if !(minimum..=maximum).contains(&length) {
                self.stream.skip(1);
                return Framed::Error(DecodeError::Length { id, actual: length, minimum, maximum });
            }
            let total = PREFIX_LEN + length;
            if data.len() < total {
                return Framed::NeedMore;
            }
            let expected = crc16(&data[..total - 2]);
            let actual = u16::from_le_bytes([data[total - 2], data[total - 1]]);
            if expected != actual {
                self.stream.skip(1);
                self.crc_errors += 1;
                return Framed::Error(DecodeError::Crc { id, expected, actual });
            }
            return Framed::Packet { id, total };
        }
    }

    fn take(&mut self, id: u8, total: usize) -> Packet<'_> {
        let n = unstuff(&self.stream.pending()[PREFIX_LEN..total - 2], &mut self.body);
        self.stream.consume(total);
        let body = &self.body[..n];
        if body[0] == STATUS {
            let error = ServoError::V2(StatusError::from_raw(body[1]));
            Packet { id, kind: Kind::Status(error), params: &body[2..] }
        } else {
            Packet { id, kind: Kind::Instruction(body[0]), params: &body[1..] }
        }
    }
}
