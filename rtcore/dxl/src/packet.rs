//! Types shared by both protocol codecs: a decoded packet, the servo's error byte as a typed
//! value, and the encode/decode errors.
//!
//! One `Packet` type serves P1 and P2 so the client, the simulated bus and the bindings handle
//! both protocols with the same code; the protocol shows only in the typed error byte.
use core::fmt;

use crate::protocol1::ErrorBits;
use crate::protocol2::StatusError;

/// Which protocol a packet or codec speaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Protocol {
    V1,
    V2,
}

impl Protocol {
    /// 1 or 2, as written in configuration files.
    pub fn from_number(n: u8) -> Option<Protocol> {
        match n {
            1 => Some(Protocol::V1),
            2 => Some(Protocol::V2),
            _ => None,
        }
    }

    pub fn number(self) -> u8 {
        match self {
            Protocol::V1 => 1,
            Protocol::V2 => 2,
        }
    }
}

/// The error byte of a status packet, decoded by protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ServoError {
    /// Protocol 2.0: an error number plus the hardware-alert bit.
    V2(StatusError),
    /// Protocol 1.0: a bitfield.
    V1(ErrorBits),
}

impl ServoError {
    pub fn raw(self) -> u8 {
        match self {
            ServoError::V2(e) => e.raw(),
            ServoError::V1(e) => e.0,
        }
    }

    /// A hardware problem is flagged (P2 alert bit; P1 voltage, overheating or overload bits).
    pub fn alert(self) -> bool {
        match self {
            ServoError::V2(e) => e.alert,
            ServoError::V1(e) => e.is_hardware(),
        }
    }

    /// The instruction itself failed (P2 error number; P1 angle/range/checksum/instruction bits).
    pub fn is_failure(self) -> bool {
        match self {
            ServoError::V2(e) => e.code.is_some(),
            ServoError::V1(e) => e.is_instruction_failure(),
        }
    }
}

impl fmt::Display for ServoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ServoError::V2(e) => e.fmt(f),
            ServoError::V1(e) => e.fmt(f),
        }
    }
}

/// What a packet is: an instruction (host → servo) or a status (servo → host).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Instruction(u8),
    Status(ServoError),
}

/// A decoded packet. `params` borrows the decoder's buffer (unstuffed), so decoding allocates
/// nothing; copy what you need before the next `Decoder::next`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Packet<'a> {
    pub id: u8,
    pub kind: Kind,
    pub params: &'a [u8],
}

/// Why an encoder refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeError {
    /// The caller's buffer is shorter than the packet.
    BufferTooSmall { needed: usize, available: usize },
    /// The packet's length field would overflow (P1: 255, P2: 65535).
    TooLong { length: usize, maximum: usize },
    /// An ID the protocol does not allow here.
    InvalidId { id: u8 },
    /// SyncWrite data is not `ids.len() × data_len` bytes, or a slice disagrees with its count.
    DataMismatch { actual: usize, expected: usize },
    /// A field (P1 address or length) does not fit its one-byte slot.
    FieldRange { field: &'static str, value: u32, maximum: u32 },
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            EncodeError::BufferTooSmall { needed, available } => {
                write!(f, "packet needs {needed} bytes but the buffer holds {available}")
            }
            EncodeError::TooLong { length, maximum } => {
                write!(f, "packet length field {length} exceeds the protocol maximum {maximum}")
            }
            EncodeError::InvalidId { id } => write!(f, "invalid Dynamixel ID {id} (0x{id:02X})"),
            EncodeError::DataMismatch { actual, expected } => {
                write!(f, "data has {actual} bytes, expected {expected}")
            }
            EncodeError::FieldRange { field, value, maximum } => {
                write!(f, "{field} {value} is above the protocol maximum {maximum}")
            }
        }
    }
}

impl std::error::Error for EncodeError {}

/// A framing error the decoder met; the bad candidate is dropped and decoding resumes at the
/// next header, so the stream is never lost.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// P2: the CRC carried by the packet differs from the one computed over its bytes.
    Crc { id: u8, expected: u16, actual: u16 },
    /// P1: the checksum carried by the packet differs from the computed one.
    Checksum { id: u8, expected: u8, actual: u8 },
    /// The length field is outside what the protocol allows (or the decoder's capacity).
    Length { id: u8, actual: usize, minimum: usize, maximum: usize },
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            DecodeError::Crc { id, expected, actual } => write!(
                f,
                "CRC mismatch on packet from ID {id}: computed 0x{expected:04X}, received 0x{actual:04X}"
            ),
            DecodeError::Checksum { id, expected, actual } => write!(
                f,
                "checksum mismatch on packet from ID {id}: computed 0x{expected:02X}, received 0x{actual:02X}"
            ),
            DecodeError::Length { id, actual, minimum, maximum } => write!(
                f,
                "bad length field {actual} on packet from ID {id} (allowed {minimum}..={maximum})"
            ),
        }
    }
}

impl std::error::Error for DecodeError {}

/// One device's slice of a BULK_READ (or BULK_WRITE): which ID, which address, how many bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BulkEntry {
    pub id: u8,
    pub address: u16,
    pub length: u16,
}
