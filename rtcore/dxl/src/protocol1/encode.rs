//! P1 encoders: whole packets into caller buffers, returning the length.
use super::{BROADCAST_ID, MAX_ID, PREFIX_LEN};
use crate::instruction as ins;
use crate::packet::{BulkEntry, EncodeError};

/// The P1 checksum over ID..last parameter (the header excluded).
pub fn checksum(bytes: &[u8]) -> u8 {
    !bytes.iter().fold(0u8, |acc, &b| acc.wrapping_add(b))
}

/// Writes a packet whose body (instruction/error + params) is `body_len` bytes filled by `fill`.
fn frame_with(
    buf: &mut [u8],
    id: u8,
    body_len: usize,
    fill: impl FnOnce(&mut [u8]) -> Result<(), EncodeError>,
) -> Result<usize, EncodeError> {
    if id > MAX_ID && id != BROADCAST_ID {
        return Err(EncodeError::InvalidId { id });
    }
    let length = body_len + 1;
    if length > 255 {
        return Err(EncodeError::TooLong { length, maximum: 255 });
    }
    let total = PREFIX_LEN + length;
    if total > buf.len() {
        return Err(EncodeError::BufferTooSmall { needed: total, available: buf.len() });
    }
    buf[..4].copy_from_slice(&[0xFF, 0xFF, id, length as u8]);
    fill(&mut buf[PREFIX_LEN..total - 1])?;
    buf[total - 1] = checksum(&buf[2..total - 1]);
    Ok(total)
}

/// Writes a packet whose body is the concatenation of `parts`.
fn frame(buf: &mut [u8], id: u8, parts: &[&[u8]]) -> Result<usize, EncodeError> {
    frame_with(buf, id, parts.iter().map(|p| p.len()).sum(), |body| {
        let mut pos = 0;
        for p in parts {
            body[pos..pos + p.len()].copy_from_slice(p);
            pos += p.len();
        }
        Ok(())
    })
}

fn byte(field: &'static str, value: u16) -> Result<u8, EncodeError> {
    u8::try_from(value).map_err(|_| EncodeError::FieldRange { field, value: value.into(), maximum: 255 })
}

fn check_devices(ids: impl IntoIterator<Item = u8>) -> Result<(), EncodeError> {
    match ids.into_iter().find(|&id| id > MAX_ID) {
        Some(id) => Err(EncodeError::InvalidId { id }),
        None => Ok(()),
    }
}

pub fn encode_instruction(buf: &mut [u8], id: u8, instruction: u8, params: &[u8]) -> Result<usize, EncodeError> {
    frame(buf, id, &[&[instruction], params])
}

/// A status packet from `id` with the raw error bitfield.
pub fn encode_status(buf: &mut [u8], id: u8, error: u8, params: &[u8]) -> Result<usize, EncodeError> {
    check_devices([id])?;
    frame(buf, id, &[&[error], params])
}

pub fn encode_ping(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::PING, &[])
}

pub fn encode_read(buf: &mut [u8], id: u8, address: u8, length: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::READ, &[address, length])
}

/// WRITE-like instruction (`address` + data), e.g. WRITE or REG_WRITE.
pub fn encode_instruction_addressed(buf: &mut [u8], id: u8, instruction: u8, address: u8, data: &[u8]) -> Result<usize, EncodeError> {
    frame(buf, id, &[&[instruction, address], data])
}

pub fn encode_write(buf: &mut [u8], id: u8, address: u8, data: &[u8]) -> Result<usize, EncodeError> {
    encode_instruction_addressed(buf, id, ins::WRITE, address, data)
}

pub fn encode_reg_write(buf: &mut [u8], id: u8, address: u8, data: &[u8]) -> Result<usize, EncodeError> {
    encode_instruction_addressed(buf, id, ins::REG_WRITE, address, data)
}

pub fn encode_action(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::ACTION, &[])
}

pub fn encode_factory_reset(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    encode_instruction(buf, id, ins::FACTORY_RESET, &[])
}

/// SYNC_WRITE of `data_len` bytes at `address`; `data` holds one record per ID, in order.
pub fn encode_sync_write(buf: &mut [u8], address: u8, data_len: u8, ids: &[u8], data: &[u8]) -> Result<usize, EncodeError> {
    let per = usize::from(data_len);
    if data.len() != ids.len() * per {
        return Err(EncodeError::DataMismatch { actual: data.len(), expected: ids.len() * per });
    }
    check_devices(ids.iter().copied())?;
    frame_with(buf, BROADCAST_ID, 3 + ids.len() * (1 + per), |body| {
        body[..3].copy_from_slice(&[ins::SYNC_WRITE, address, data_len]);
        for (i, &id) in ids.iter().enumerate() {
            let at = 3 + i * (1 + per);
            body[at] = id;
            body[at + 1..at + 1 + per].copy_from_slice(&data[i * per..(i + 1) * per]);
        }
        Ok(())
    })
}

/// BULK_READ (MX series): params `00`, then per entry `length, id, address` (P1 order).
pub fn encode_bulk_read(buf: &mut [u8], entries: &[BulkEntry]) -> Result<usize, EncodeError> {
    check_devices(entries.iter().map(|e| e.id))?;
    frame_with(buf, BROADCAST_ID, 2 + 3 * entries.len(), |body| {
        body[..2].copy_from_slice(&[ins::BULK_READ, 0x00]);
        for (e, slot) in entries.iter().zip(body[2..].chunks_exact_mut(3)) {
            slot.copy_from_slice(&[byte("bulk-read length", e.length)?, e.id, byte("address", e.address)?]);
        }
        Ok(())
    })
}
