//! Instruction packets parsed into protocol-neutral requests.
//!
//! P1 and P2 differ in field widths (1-byte vs 2-byte addresses and lengths) and in the Bulk
//! Read layout (P1: `00, (len, id, addr)…`; P2: `(id, addr, len)…`), but a servo does the same
//! thing for both. Parsing once into `Request` lets `bus` execute every instruction with one
//! piece of code per instruction, whatever the protocol.
use dxl::instruction as ins;
use dxl::Protocol;

/// One device's part of a Sync/Bulk Read: who, where, how many bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReadSlot {
    pub id: u8,
    pub address: u16,
    pub length: u16,
}

/// One device's part of a Sync/Bulk Write.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WriteSlot {
    pub id: u8,
    pub address: u16,
    pub data: Vec<u8>,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request {
    Ping,
    Read { address: u16, length: u16 },
    Write { address: u16, data: Vec<u8> },
    RegWrite { address: u16, data: Vec<u8> },
    Action,
    FactoryReset { option: u8 },
    Reboot,
    /// CLEAR (P2) with its magic parameters: fold the multi-turn position into one turn.
    ClearTurns,
    /// Sync Read and Bulk Read: replies in listed order.
    MultiRead(Vec<ReadSlot>),
    /// Fast Sync Read: one combined reply, the listed servos' segments in listed order.
    FastSyncRead(Vec<ReadSlot>),
    /// Sync Write and Bulk Write: no reply.
    MultiWrite(Vec<WriteSlot>),
}

/// Why an instruction could not become a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParseError {
    /// An instruction this servo does not implement (or this protocol does not have).
    Unknown,
    /// A known instruction whose parameters have the wrong length or shape.
    Malformed,
}

/// CLEAR's parameters for "reset the multi-turn position" (option 1 and the "DXL\"" key).
const CLEAR_TURNS: &[u8] = &[0x01, 0x44, 0x58, 0x4C, 0x22];

/// Parses one instruction's parameters.
pub fn parse(protocol: Protocol, instruction: u8, params: &[u8]) -> Result<Request, ParseError> {
    let wide = protocol == Protocol::V2;
    match instruction {
        ins::PING => Ok(Request::Ping),
        ins::READ => {
            let (address, rest) = field(params, wide)?;
            let (length, rest) = field(rest, wide)?;
            exact(rest, 0)?;
            Ok(Request::Read { address, length })
        }
        ins::WRITE | ins::REG_WRITE => {
            let (address, data) = field(params, wide)?;
            if data.is_empty() {
                return Err(ParseError::Malformed);
            }
            let data = data.to_vec();
            Ok(if instruction == ins::WRITE { Request::Write { address, data } } else { Request::RegWrite { address, data } })
        }
        ins::ACTION => Ok(Request::Action),
        ins::FACTORY_RESET => Ok(Request::FactoryReset { option: params.first().copied().unwrap_or(0xFF) }),
        ins::REBOOT if wide => Ok(Request::Reboot),
        ins::CLEAR if wide => match params {
            CLEAR_TURNS => Ok(Request::ClearTurns),
            _ => Err(ParseError::Malformed),
        },
        ins::SYNC_READ if wide => sync_read(params).map(Request::MultiRead),
        ins::FAST_SYNC_READ if wide => sync_read(params).map(Request::FastSyncRead),
        ins::SYNC_WRITE => sync_write(params, wide),
        ins::BULK_READ if wide => bulk_read_p2(params),
        ins::BULK_READ => bulk_read_p1(params),
        ins::BULK_WRITE if wide => bulk_write_p2(params),
        _ => Err(ParseError::Unknown),
    }
}

/// A little-endian address or length: 2 bytes on P2, 1 on P1.
fn field(bytes: &[u8], wide: bool) -> Result<(u16, &[u8]), ParseError> {
    if wide {
        match bytes {
            [lo, hi, rest @ ..] => Ok((u16::from_le_bytes([*lo, *hi]), rest)),
            _ => Err(ParseError::Malformed),
        }
    } else {
        match bytes {
            [b, rest @ ..] => Ok((*b as u16, rest)),
            _ => Err(ParseError::Malformed),
        }
    }
}

fn exact(rest: &[u8], n: usize) -> Result<(), ParseError> {
    if rest.len() == n {
        Ok(())
    } else {
        Err(ParseError::Malformed)
    }
}

/// Sync Read's and Fast Sync Read's parameters (the same bytes): one slot per listed ID.
fn sync_read(params: &[u8]) -> Result<Vec<ReadSlot>, ParseError> {
    let (address, rest) = field(params, true)?;
    let (length, ids) = field(rest, true)?;
    if ids.is_empty() || length == 0 {
        return Err(ParseError::Malformed);
    }
    Ok(ids.iter().map(|&id| ReadSlot { id, address, length }).collect())
}

fn sync_write(params: &[u8], wide: bool) -> Result<Request, ParseError> {
    let (address, rest) = field(params, wide)?;
    let (length, body) = field(rest, wide)?;
    let stride = 1 + length as usize;
    if length == 0 || body.is_empty() || !body.len().is_multiple_of(stride) {
        return Err(ParseError::Malformed);
    }
    let slots = body.chunks(stride).map(|c| WriteSlot { id: c[0], address, data: c[1..].to_vec() }).collect();
    Ok(Request::MultiWrite(slots))
}

fn bulk_read_p2(params: &[u8]) -> Result<Request, ParseError> {
    if params.is_empty() || !params.len().is_multiple_of(5) {
        return Err(ParseError::Malformed);
    }
    let slots = params
        .chunks(5)
        .map(|c| ReadSlot {
            id: c[0],
            address: u16::from_le_bytes([c[1], c[2]]),
            length: u16::from_le_bytes([c[3], c[4]]),
        })
        .collect();
    Ok(Request::MultiRead(slots))
}

fn bulk_read_p1(params: &[u8]) -> Result<Request, ParseError> {
    match params {
        [0, body @ ..] if !body.is_empty() && body.len().is_multiple_of(3) => Ok(Request::MultiRead(
            body.chunks(3).map(|c| ReadSlot { id: c[1], address: c[2] as u16, length: c[0] as u16 }).collect(),
        )),
        _ => Err(ParseError::Malformed),
    }
}

fn bulk_write_p2(mut params: &[u8]) -> Result<Request, ParseError> {
    let mut slots = Vec::new();
    while !params.is_empty() {
        let [id, a0, a1, l0, l1, rest @ ..] = params else { return Err(ParseError::Malformed) };
        let length = u16::from_le_bytes([*l0, *l1]) as usize;
        if length == 0 || rest.len() < length {
            return Err(ParseError::Malformed);
        }
        slots.push(WriteSlot { id: *id, address: u16::from_le_bytes([*a0, *a1]), data: rest[..length].to_vec() });
        params = &rest[length..];
    }
    Ok(Request::MultiWrite(slots))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn p2_sync_read_lists_ids_in_order() {
        let r = parse(Protocol::V2, ins::SYNC_READ, &[0x84, 0, 4, 0, 3, 1, 2]).unwrap();
        let ids: Vec<u8> = match r {
            Request::MultiRead(s) => s.iter().map(|s| s.id).collect(),
            other => panic!("{other:?}"),
        };
        assert_eq!(ids, [3, 1, 2]);
    }

    #[test]
    fn p1_bulk_read_uses_len_id_addr_order() {
        // The e-manual example: ID1 addr 0x1E len 2, ID2 addr 0x24 len 2.
        let r = parse(Protocol::V1, ins::BULK_READ, &[0x00, 0x02, 0x01, 0x1E, 0x02, 0x02, 0x24]).unwrap();
        assert_eq!(
            r,
            Request::MultiRead(vec![
                ReadSlot { id: 1, address: 0x1E, length: 2 },
                ReadSlot { id: 2, address: 0x24, length: 2 }
            ])
        );
    }

    #[test]
    fn p1_sync_write_splits_per_device() {
        // The e-manual example: addr 30, 4 bytes each for ID0 and ID1.
        let params = [0x1E, 0x04, 0x00, 0x10, 0x00, 0x50, 0x01, 0x01, 0x20, 0x02, 0x60, 0x03];
        let Request::MultiWrite(slots) = parse(Protocol::V1, ins::SYNC_WRITE, &params).unwrap() else { panic!() };
        assert_eq!(slots[1], WriteSlot { id: 1, address: 30, data: vec![0x20, 0x02, 0x60, 0x03] });
    }

    #[test]
    fn p2_bulk_write_has_variable_lengths() {
        let params = [1, 0x20, 0, 2, 0, 0xA0, 0, 2, 0x1F, 0, 1, 0, 0x50];
        let Request::MultiWrite(slots) = parse(Protocol::V2, ins::BULK_WRITE, &params).unwrap() else { panic!() };
        assert_eq!(slots.len(), 2);
        assert_eq!(slots[1].data, vec![0x50]);
    }

    #[test]
    fn instructions_p1_lacks_are_unknown() {
        assert_eq!(parse(Protocol::V1, ins::REBOOT, &[]), Err(ParseError::Unknown));
        assert_eq!(parse(Protocol::V1, ins::SYNC_READ, &[0, 4, 1]), Err(ParseError::Unknown));
        assert_eq!(parse(Protocol::V2, 0x77, &[]), Err(ParseError::Unknown));
    }

    #[test]
    fn short_reads_are_malformed() {
        assert_eq!(parse(Protocol::V2, ins::READ, &[0x84, 0, 4]), Err(ParseError::Malformed));
        assert_eq!(parse(Protocol::V1, ins::READ, &[0x24]), Err(ParseError::Malformed));
    }

    proptest! {
        #[test]
        fn any_parameters_parse_or_fail_without_panicking(
            instruction in any::<u8>(), params in proptest::collection::vec(any::<u8>(), 0..64), v2 in any::<bool>()
        ) {
            let protocol = if v2 { Protocol::V2 } else { Protocol::V1 };
            let _ = parse(protocol, instruction, &params);
        }
    }
}
