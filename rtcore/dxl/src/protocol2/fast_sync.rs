//! Fast Sync Read (instruction 0x8A): one status packet for all servos (shared protocols.md §7).
//!
//! The instruction is a Sync Read with another code. The reply is one packet with ID 0xFE:
//! `FF FF FD 00 FE LEN_L LEN_H 55 | ERR1 ID1 data1[X] CRC1 | ... | ERRn IDn datan[X] CRCn`,
//! LEN = 1 + Σ(4 + X). Each servo sends only its own segment, in the listed order; each
//! segment's CRC is the running CRC of every byte from the packet's first FF to the end of that
//! segment's data, so the last one is the packet's CRC. The reply is not byte-stuffed.
//!
//! Why it matters: one header and one Return Delay Time for the whole bus instead of one per
//! servo; with 6 servos the reply shrinks from 6 × (11 + X) bytes to 8 + 6 × (4 + X).
use super::encode::encode_sync_read_as;
use super::{BROADCAST_ID, HEADER, PREFIX_LEN};
use crate::crc::crc16_update;
use crate::instruction as ins;
use crate::packet::EncodeError;

/// FAST_SYNC_READ of `length` bytes at `address` from each of `ids` (their segments come in `ids` order).
pub fn encode_fast_sync_read(buf: &mut [u8], address: u16, length: u16, ids: &[u8]) -> Result<usize, EncodeError> {
    encode_sync_read_as(buf, ins::FAST_SYNC_READ, address, length, ids)
}

/// Bytes of the whole reply for `n` servos of `x` data bytes each: 8 + n·(4 + x).
pub const fn fast_sync_reply_len(n: usize, x: usize) -> usize {
    PREFIX_LEN + 1 + n * (4 + x)
}

/// The prefix of the reply (header, 0xFE, LEN, 0x55) for `n` servos of `x` bytes: what the
/// first servo sends before its segment.
pub fn fast_sync_reply_prefix(n: usize, x: usize) -> [u8; 8] {
    let len = (1 + n * (4 + x)) as u16;
    let [lo, hi] = len.to_le_bytes();
    [HEADER[0], HEADER[1], HEADER[2], HEADER[3], BROADCAST_ID, lo, hi, ins::STATUS]
}

/// One servo's segment, appended to `out` (which holds the reply so far, prefix included):
/// ERR, ID, data, and the running CRC over everything before it.
pub fn push_fast_sync_segment(out: &mut Vec<u8>, crc_so_far: u16, id: u8, error: u8, data: &[u8]) -> u16 {
    let start = out.len();
    out.push(error);
    out.push(id);
    out.extend_from_slice(data);
    let crc = crc16_update(crc_so_far, &out[start..]);
    out.extend_from_slice(&crc.to_le_bytes());
    crc16_update(crc, &crc.to_le_bytes())
}

/// Why a Fast Sync Read reply does not decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FastSyncError {
    /// Shorter than its LEN says, or LEN is not 1 + n·(4 + x).
    Length,
    /// Not `FF FF FD 00 FE .. .. 55`.
    Header,
    /// The segment at this index fails its running CRC.
    Crc(usize),
    /// The segment at this index carries another ID than the one listed there.
    Id(usize),
}

/// Check a whole reply for `ids` (listed order) of `x` bytes each; `segment(k, error, data)` is
/// called for each servo once every CRC holds (nothing is handed on from a bad reply).
pub fn decode_fast_sync_reply(reply: &[u8], ids: &[u8], x: usize, segment: impl FnMut(usize, u8, &[u8])) -> Result<(), FastSyncError> {
    if reply.len() < fast_sync_reply_len(ids.len(), x) {
        return Err(FastSyncError::Length);
    }
    decode_fast_sync_prefix(reply, ids, x, segment).map(drop)
}

/// Check the part of a reply that arrived: `reply` holds its first bytes (bytes beyond the
/// reply's length are ignored). Returns how many segments (the first listed servos') arrived
/// whole with their running CRC and ID right, after handing each to `segment(k, error, data)`.
///
/// Why a cut reply still says something: each segment's CRC covers every byte before it, so
/// the segments that arrived are certain, and the servos whose segments did not come are the
/// listed ones after them. A wrong byte anywhere (prefix, a whole segment's CRC or ID) is an
/// error, and then nothing is handed on.
pub fn decode_fast_sync_prefix(reply: &[u8], ids: &[u8], x: usize, mut segment: impl FnMut(usize, u8, &[u8])) -> Result<usize, FastSyncError> {
    let reply = &reply[..reply.len().min(fast_sync_reply_len(ids.len(), x))];
    let prefix = fast_sync_reply_prefix(ids.len(), x);
    let head = reply.len().min(PREFIX_LEN + 1);
    if reply[..head] != prefix[..head] {
        let same_head = head == PREFIX_LEN + 1
            && reply[..5] == [HEADER[0], HEADER[1], HEADER[2], HEADER[3], BROADCAST_ID]
            && reply[7] == ins::STATUS;
        return Err(if same_head { FastSyncError::Length } else { FastSyncError::Header });
    }
    let stride = 4 + x;
    let whole = reply.len().saturating_sub(PREFIX_LEN + 1) / stride;
    let mut crc = crc16_update(0, &reply[..head]);
    for (k, &id) in ids.iter().enumerate().take(whole) {
        let at = PREFIX_LEN + 1 + k * stride;
        let body = &reply[at..at + 2 + x];
        crc = crc16_update(crc, body);
        let stated = u16::from_le_bytes([reply[at + 2 + x], reply[at + 3 + x]]);
        if stated != crc {
            return Err(FastSyncError::Crc(k));
        }
        if body[1] != id {
            return Err(FastSyncError::Id(k));
        }
        crc = crc16_update(crc, &reply[at + 2 + x..at + 4 + x]);
    }
    for k in 0..whole {
        let at = PREFIX_LEN + 1 + k * stride;
        segment(k, reply[at], &reply[at + 2..at + 2 + x]);
    }
    Ok(whole)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_instruction_matches_the_e_manual_example() {
        // protocols.md: Fast Sync Read addr 132 len 4 IDs 3,7,4 → CRC 20 F2 [verified]
        let mut buf = [0u8; 32];
        let n = encode_fast_sync_read(&mut buf, 132, 4, &[3, 7, 4]).unwrap();
        assert_eq!(&buf[..n], &[0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x0A, 0x00, 0x8A, 0x84, 0x00, 0x04, 0x00, 0x03, 0x07, 0x04, 0x20, 0xF2]);
    }

    fn reply(ids: &[u8], values: &[u32]) -> Vec<u8> {
        let mut out = fast_sync_reply_prefix(ids.len(), 4).to_vec();
        let mut crc = crc16_update(0, &out);
        for (&id, v) in ids.iter().zip(values) {
            crc = push_fast_sync_segment(&mut out, crc, id, 0, &v.to_le_bytes());
        }
        out
    }

    #[test]
    fn the_reply_matches_the_e_manual_segment_crcs() {
        // The e-manual's example reply (IDs 3, 7, 4; positions 166, 2079, 1023) with the segment
        // CRCs protocols.md lists as verified: 84 08, 16 CA, D1 9E.
        let example = [
            0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x19, 0x00, 0x55, 0x00, 0x03, 0xA6, 0x00, 0x00, 0x00, 0x84, 0x08, 0x00, 0x07,
            0x1F, 0x08, 0x00, 0x00, 0x16, 0xCA, 0x00, 0x04, 0xFF, 0x03, 0x00, 0x00, 0xD1, 0x9E,
        ];
        let mut got = Vec::new();
        decode_fast_sync_reply(&example, &[3, 7, 4], 4, |k, e, d| got.push((k, e, u32::from_le_bytes([d[0], d[1], d[2], d[3]])))).unwrap();
        assert_eq!(got, vec![(0, 0, 0xA6), (1, 0, 0x81F), (2, 0, 0x3FF)]);
        assert_eq!(reply(&[3, 7, 4], &[0xA6, 0x81F, 0x3FF]), example.to_vec());
    }

    #[test]
    fn a_bad_segment_or_a_short_reply_hands_nothing_on() {
        let good = reply(&[1, 2], &[10, 20]);
        let mut calls = 0;
        for (k, bad) in [(0, 10usize), (1, 18)] {
            let mut r = good.clone();
            r[bad] ^= 1;
            assert_eq!(decode_fast_sync_reply(&r, &[1, 2], 4, |_, _, _| calls += 1), Err(FastSyncError::Crc(k)));
        }
        assert_eq!(decode_fast_sync_reply(&good[..good.len() - 1], &[1, 2], 4, |_, _, _| calls += 1), Err(FastSyncError::Length));
        assert_eq!(decode_fast_sync_reply(&good, &[2, 1], 4, |_, _, _| calls += 1), Err(FastSyncError::Id(0)));
        assert_eq!(calls, 0);
        assert_eq!(fast_sync_reply_len(6, 4), good.len() - 2 * 8 + 6 * 8);
    }

    #[test]
    fn a_cut_reply_hands_on_the_segments_that_arrived_whole() {
        let good = reply(&[1, 2, 3], &[10, 20, 30]);
        let mut got = Vec::new();
        // Cut inside the third segment: the first two are certain, the third missing.
        let whole = decode_fast_sync_prefix(&good[..good.len() - 3], &[1, 2, 3], 4, |k, _, d| got.push((k, d[0]))).unwrap();
        assert_eq!((whole, got), (2, vec![(0, 10), (1, 20)]));
        assert_eq!(decode_fast_sync_prefix(&good[..5], &[1, 2, 3], 4, |_, _, _| {}), Ok(0), "a prefix's start");
        assert_eq!(decode_fast_sync_prefix(&[], &[1, 2, 3], 4, |_, _, _| {}), Ok(0));
        assert_eq!(decode_fast_sync_prefix(&[0xFF, 0xFF, 0xFD, 0x00, 0x01], &[1], 4, |_, _, _| {}), Err(FastSyncError::Header));
        assert_eq!(decode_fast_sync_reply(&good[..good.len() - 3], &[1, 2, 3], 4, |_, _, _| {}), Err(FastSyncError::Length));
    }

    proptest::proptest! {
        /// Any corruption of a whole reply, any cut, any bytes at all: no panic, and nothing
        /// handed on that the servos did not send.
        #[test]
        fn corrupt_or_cut_replies_never_pass_for_what_was_sent(
            values in proptest::collection::vec(proptest::prelude::any::<u32>(), 1..13),
            flip_at in proptest::prelude::any::<proptest::sample::Index>(),
            flip in 1u8..=255,
            cut in proptest::prelude::any::<proptest::sample::Index>(),
            noise in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..120),
        ) {
            let ids: Vec<u8> = (1..=values.len() as u8).collect();
            let good = reply(&ids, &values);
            let mut bad = good.clone();
            let at = flip_at.index(bad.len());
            bad[at] ^= flip;
            // A flipped byte is always caught (a CRC-16 catches every error burst of 16 bits or
            // fewer), unless it falls in a segment that did not arrive.
            let rejected = decode_fast_sync_reply(&bad, &ids, 4, |_, _, _| {}).is_err();
            proptest::prop_assert!(rejected);
            let cut = cut.index(good.len() + 1);
            let mut seen = Vec::new();
            let whole = decode_fast_sync_prefix(&good[..cut], &ids, 4, |k, e, d| seen.push((k, e, d.to_vec()))).unwrap();
            proptest::prop_assert_eq!(whole, cut.saturating_sub(8) / 8);
            for (k, e, d) in seen {
                proptest::prop_assert_eq!((e, d), (0, values[k].to_le_bytes().to_vec()));
            }
            let mut calls = 0;
            let result = decode_fast_sync_prefix(&bad[..cut], &ids, 4, |_, _, _| calls += 1);
            if at < cut && at < 8 + 8 * (cut.saturating_sub(8) / 8) {
                proptest::prop_assert!(result.is_err() && calls == 0, "a bad byte inside what arrived: {result:?}");
            }
            let _ = decode_fast_sync_prefix(&noise, &ids, 4, |_, _, _| {});
        }
    }
}
