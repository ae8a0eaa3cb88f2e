//! The streaming P1 decoder. P1 frames do not say whether they carry an instruction or a
//! status (byte 4 is INST or ERR), so the decoder is told which side of the bus it sits on.
//! Like the P2 decoder it skips and counts garbage, drops only one byte after a bad candidate
//! (so a real packet inside it is still found) and never panics.
use super::encode::checksum;
use super::{ErrorBits, MAX_PACKET_LEN, PREFIX_LEN};
use crate::packet::{DecodeError, Kind, Packet, ServoError};
use crate::stream::ByteStream;

/// Which packets the stream carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Expect {
    /// Host → servo (a servo or a simulated bus listening).
    Instruction,
    /// Servo → host (a client listening).
    Status,
}

pub struct Decoder {
    stream: ByteStream,
    /// The last packet, copied out so the stream can move on while the caller holds it.
    packet: Box<[u8]>,
    expect: Expect,
    checksum_errors: u64,
}

impl Decoder {
    pub fn new(expect: Expect) -> Decoder {
        Decoder {
            stream: ByteStream::with_capacity(2 * MAX_PACKET_LEN),
            packet: vec![0; MAX_PACKET_LEN].into_boxed_slice(),
            expect,
            checksum_errors: 0,
        }
    }

    /// Buffer bytes; returns how many fit. Call `next` until `None` before pushing the rest.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        self.stream.push(bytes)
    }

    pub fn skipped_bytes(&self) -> u64 {
        self.stream.skipped()
    }

    pub fn checksum_errors(&self) -> u64 {
        self.checksum_errors
    }

    pub fn buffered(&self) -> usize {
        self.stream.pending().len()
    }

    pub fn clear(&mut self) {
        self.stream.clear();
    }

    /// The next packet or framing error, or `None` when more bytes are needed.
    #[allow(clippy::should_implement_trait)] // a lending iterator: packets borrow the decoder
    pub fn next(&mut self) -> Option<Result<Packet<'_>, DecodeError>> {
        let total = match self.frame() {
            Ok(Some(total)) => total,
            Ok(None) => return None,
            Err(e) => return Some(Err(e)),
        };
        self.packet[..total].copy_from_slice(&self.stream.pending()[..total]);
        self.stream.consume(total);
        let data = &self.packet[..total];
        let kind = match self.expect {
            Expect::Instruction => Kind::Instruction(data[4]),
            Expect::Status => Kind::Status(ServoError::V1(ErrorBits(data[4]))),
        };
        Some(Ok(Packet { id: data[2], kind, params: &data[5..total - 1] }))
    }

    /// Find and check the next candidate; `Ok(Some(total))` leaves a valid packet at the front.
    fn frame(&mut self) -> Result<Option<usize>, DecodeError> {
        loop {
            if !self.stream.seek_header(&[0xFF, 0xFF]) {
                return Ok(None);
            }
            let data = self.stream.pending();
            if data.len() < PREFIX_LEN {
                return Ok(None);
            }
            let id = data[2];
            if id == 0xFF {
                self.stream.skip(1);
                continue;
            }
            let length = usize::from(data[3]);
            if length < 2 {
                self.stream.skip(1);
                return Err(DecodeError::Length { id, actual: length, minimum: 2, maximum: 255 });
            }
            let total = PREFIX_LEN + length;
            if data.len() < total {
                return Ok(None);
            }
            let expected = checksum(&data[2..total - 1]);
            let actual = data[total - 1];
            if expected != actual {
                self.stream.skip(1);
                self.checksum_errors += 1;
                return Err(DecodeError::Checksum { id, expected, actual });
            }
            return Ok(Some(total));
        }
    }
}
