//! P2 encoders. Each writes one whole packet into a caller buffer and returns its length, so
//! the RT loop reuses one preallocated buffer per cycle. Stuffing happens while writing (one
//! pass, no scratch buffer), the length field is patched afterwards and the CRC goes last.
use super::stuffing::{stuffed_len_of, PatternMatcher};
use super::{BROADCAST_ID, HEADER, MAX_ID, PREFIX_LEN};
use crate::crc::crc16;
use crate::instruction as ins;
use crate::packet::{BulkEntry, EncodeError};

/// Writes the stuffed body of a packet. It keeps counting past the end of a short buffer, so
/// the error can say exactly how many bytes the packet needs.
struct BodyWriter<'a> {
    buf: &'a mut [u8],
    pos: usize,
    matcher: PatternMatcher,
}

impl BodyWriter<'_> {
    fn put(&mut self, b: u8) {
        if let Some(slot) = self.buf.get_mut(self.pos) {
            *slot = b;
        }
        self.pos += 1;
        if self.matcher.feed(b) {
            self.matcher.reset();
            self.put(0xFD);
        }
    }

    fn put_all(&mut self, bytes: &[u8]) {
        bytes.iter().for_each(|&b| self.put(b));
    }

    fn put_u16(&mut self, v: u16) {
        self.put_all(&v.to_le_bytes());
    }
}

/// Frame a packet: header, ID, length, then `body` writes the scanned (stuffed) bytes.
fn frame(buf: &mut [u8], id: u8, body: impl FnOnce(&mut BodyWriter)) -> Result<usize, EncodeError> {
    let mut w = BodyWriter { buf, pos: PREFIX_LEN, matcher: PatternMatcher::default() };
    body(&mut w);
    let end = w.pos;
    let length = end - PREFIX_LEN + 2;
    if length > u16::MAX as usize {
        return Err(EncodeError::TooLong { length, maximum: u16::MAX as usize });
    }
    if end + 2 > buf.len() {
        return Err(EncodeError::BufferTooSmall { needed: end + 2, available: buf.len() });
    }
    buf[..4].copy_from_slice(&HEADER);
    buf[4] = id;
    buf[5..7].copy_from_slice(&(length as u16).to_le_bytes());
    let crc = crc16(&buf[..end]);
    buf[end..end + 2].copy_from_slice(&crc.to_le_bytes());
    Ok(end + 2)
}

fn check_target(id: u8) -> Result<(), EncodeError> {
    if id <= MAX_ID || id == BROADCAST_ID {
        Ok(())
    } else {
        Err(EncodeError::InvalidId { id })
    }
}

fn check_device(id: u8) -> Result<(), EncodeError> {
    if id <= MAX_ID {
        Ok(())
    } else {
        Err(EncodeError::InvalidId { id })
    }
}

fn check_data_len(actual: usize, expected: usize) -> Result<(), EncodeError> {
    if actual == expected {
        Ok(())
    } else {
        Err(EncodeError::DataMismatch { actual, expected })
    }
}

/// Any instruction packet to `id` (0..=0xFC or broadcast 0xFE) with raw parameters.
pub fn encode_instruction(buf: &mut [u8], id: u8, instruction: u8, params: &[u8]) -> Result<usize, EncodeError> {
    check_target(id)?;
    frame(buf, id, |w| {
        w.put(instruction);
        w.put_all(params);
    })
}

/// A status packet (instruction 0x55) from device `id`, with the raw error byte.
pub fn encode_status(buf: &mut [u8], id: u8, error: u8, params: &[u8]) -> Result<usize, EncodeError> {
    check_device(id)?;
    frame(buf, id, |w| {
        w.put(ins::STATUS);
        w.put(error);
        w.put_all(params);
    })
}

/// Size of an instruction packet (after stuffing); for sizing buffers.
pub fn instruction_len(instruction: u8, params: &[u8]) -> usize {
    PREFIX_LEN + stuffed_len_of(core::iter::once(instruction).chain(params.iter().copied())) + 2
}

/// Size of a status packet (after stuffing).
pub fn status_len(error: u8, params: &[u8]) -> usize {
    PREFIX_LEN + stuffed_len_of([ins::STATUS, error].into_iter().chain(params.iter().copied())) + 2
}

pub fn encode_ping(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::PING, &[])
}

pub fn encode_read(buf: &mut [u8], id: u8, address: u16, length: u16) -> Result<usize, EncodeError> {
    let [a0, a1] = address.to_le_bytes();
    let [l0, l1] = length.to_le_bytes();
    encode_instruction(buf, id, ins::READ, &[a0, a1, l0, l1])
}

/// WRITE-like instruction (`address` + data), e.g. WRITE or REG_WRITE.
pub fn encode_addressed(buf: &mut [u8], id: u8, instruction: u8, address: u16, data: &[u8]) -> Result<usize, EncodeError> {
    check_target(id)?;
    frame(buf, id, |w| {
        w.put(instruction);
        w.put_u16(address);
        w.put_all(data);
    })
}

pub fn encode_write(buf: &mut [u8], id: u8, address: u16, data: &[u8]) -> Result<usize, EncodeError> {
    encode_addressed(buf, id, ins::WRITE, address, data)
}

pub fn encode_reg_write(buf: &mut [u8], id: u8, address: u16, data: &[u8]) -> Result<usize, EncodeError> {
    encode_addressed(buf, id, ins::REG_WRITE, address, data)
}

pub fn encode_action(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::ACTION, &[])
}

/// `option`: 0xFF reset all, 0x01 all but ID, 0x02 all but ID and baud rate.
pub fn encode_factory_reset(buf: &mut [u8], id: u8, option: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::FACTORY_RESET, &[option])
}

pub fn encode_reboot(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::REBOOT, &[])
}

/// CLEAR of the multi-turn position (the fixed key `01 44 58 4C 22`).
pub fn encode_clear(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::CLEAR, &[0x01, 0x44, 0x58, 0x4C, 0x22])
}

/// SYNC_READ of `length` bytes at `address` from each of `ids`; replies come in `ids` order.
pub fn encode_sync_read(buf: &mut [u8], address: u16, length: u16, ids: &[u8]) -> Result<usize, EncodeError> {
    encode_sync_read_as(buf, ins::SYNC_READ, address, length, ids)
}

/// A Sync Read's parameters under `instruction` (SYNC_READ, or FAST_SYNC_READ: same bytes).
pub(super) fn encode_sync_read_as(buf: &mut [u8], instruction: u8, address: u16, length: u16, ids: &[u8]) -> Result<usize, EncodeError> {
    ids.iter().try_for_each(|&id| check_device(id))?;
    frame(buf, BROADCAST_ID, |w| {
        w.put(instruction);
        w.put_u16(address);
        w.put_u16(length);
        w.put_all(ids);
    })
}

/// SYNC_WRITE of `data_len` bytes at `address`; `data` holds `ids.len()` records of
/// `data_len` bytes, one per ID in the same order (a flat slice: nothing to allocate).
pub fn encode_sync_write(
    buf: &mut [u8],
    address: u16,
    data_len: u16,
    ids: &[u8],
    data: &[u8],
) -> Result<usize, EncodeError> {
    let per = usize::from(data_len);
    check_data_len(data.len(), ids.len() * per)?;
    ids.iter().try_for_each(|&id| check_device(id))?;
    frame(buf, BROADCAST_ID, |w| {
        w.put(ins::SYNC_WRITE);
        w.put_u16(address);
        w.put_u16(data_len);
        for (i, &id) in ids.iter().enumerate() {
            w.put(id);
            w.put_all(&data[i * per..(i + 1) * per]);
        }
    })
}

/// BULK_READ: each entry names its own ID, address and length; replies come in entry order.
pub fn encode_bulk_read(buf: &mut [u8], entries: &[BulkEntry]) -> Result<usize, EncodeError> {
    entries.iter().try_for_each(|e| check_device(e.id))?;
    frame(buf, BROADCAST_ID, |w| {
        w.put(ins::BULK_READ);
        for e in entries {
            w.put(e.id);
            w.put_u16(e.address);
            w.put_u16(e.length);
        }
    })
}

/// BULK_WRITE: `data` is the concatenation of each entry's `length` bytes, in entry order.
pub fn encode_bulk_write(buf: &mut [u8], entries: &[BulkEntry], data: &[u8]) -> Result<usize, EncodeError> {
    let total: usize = entries.iter().map(|e| usize::from(e.length)).sum();
    check_data_len(data.len(), total)?;
    entries.iter().try_for_each(|e| check_device(e.id))?;
    frame(buf, BROADCAST_ID, |w| {
        w.put(ins::BULK_WRITE);
        let mut off = 0;
        for e in entries {
            let n = usize::from(e.length);
            w.put(e.id);
            w.put_u16(e.address);
            w.put_u16(e.length);
            w.put_all(&data[off..off + n]);
            off += n;
        }
    })
}
