//! One decoder type for either protocol, for code that picks the protocol at run time
//! (the client, the Python binding, the simulated bus).
use crate::packet::{DecodeError, Packet, Protocol};
use crate::{protocol1 as p1, protocol2 as p2};

pub enum AnyDecoder {
    V1(p1::Decoder),
    V2(p2::Decoder),
}

impl AnyDecoder {
    /// A P2 decoder reads both directions; a P1 decoder must be told which (`expect`).
    pub fn new(protocol: Protocol, expect: p1::Expect) -> AnyDecoder {
        match protocol {
            Protocol::V1 => AnyDecoder::V1(p1::Decoder::new(expect)),
            Protocol::V2 => AnyDecoder::V2(p2::Decoder::new()),
        }
    }

    pub fn protocol(&self) -> Protocol {
        match self {
            AnyDecoder::V1(_) => Protocol::V1,
            AnyDecoder::V2(_) => Protocol::V2,
        }
    }

    pub fn push(&mut self, bytes: &[u8]) -> usize {
        match self {
            AnyDecoder::V1(d) => d.push(bytes),
            AnyDecoder::V2(d) => d.push(bytes),
        }
    }

    #[allow(clippy::should_implement_trait)] // a lending iterator: packets borrow the decoder
    pub fn next(&mut self) -> Option<Result<Packet<'_>, DecodeError>> {
        match self {
            AnyDecoder::V1(d) => d.next(),
            AnyDecoder::V2(d) => d.next(),
        }
    }

    pub fn clear(&mut self) {
        match self {
            AnyDecoder::V1(d) => d.clear(),
            AnyDecoder::V2(d) => d.clear(),
        }
    }

    pub fn skipped_bytes(&self) -> u64 {
        match self {
            AnyDecoder::V1(d) => d.skipped_bytes(),
            AnyDecoder::V2(d) => d.skipped_bytes(),
        }
    }

    /// CRC (P2) or checksum (P1) failures so far.
    pub fn integrity_errors(&self) -> u64 {
        match self {
            AnyDecoder::V1(d) => d.checksum_errors(),
            AnyDecoder::V2(d) => d.crc_errors(),
        }
    }
}
