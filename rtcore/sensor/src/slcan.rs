//! The Lawicel ("slcan") ASCII protocol from the host's side: what a USB-CAN adapter in slcan
//! mode (CANable, CANUSB, the mock bench's simulated adapter) writes on its serial port.
//!
//! Lines end in CR. A received data frame is `tIIIL<2L hex>` (11-bit id) or `TIIIIIIIIL...`
//! (29-bit), optionally followed by a 4-digit millisecond timestamp (after `Z1`); the adapter
//! answers commands with CR (accepted), BEL (refused), `z`/`Z` (transmitted), or a reply line.
//! At open the host sends `C` (close, accepted in any state), `S<code>` (the bit rate, only
//! while closed) and `O`: the sequence python-can's slcan interface sends.
//!
//! A line that does not decode (noise on the USB serial line, a cut line) is counted and
//! dropped; its lost bytes cost the OptoForce parser one checksum error or resync, as a lost
//! CAN frame does. The line buffer is bounded: an adapter that never sends CR cannot grow it.

/// No slcan line is longer (`T` + 8 + 1 + 16 + 4 = 30); longer is garbage.
const MAX_LINE: usize = 64;
const BEL: u8 = 0x07;

/// The `S<code>` of a bit rate, as the Lawicel table has it.
pub fn bitrate_command(bitrate: u32) -> Result<Vec<u8>, String> {
    const CODES: [(u32, u8); 10] = [
        (10_000, b'0'), (20_000, b'1'), (50_000, b'2'), (100_000, b'3'), (125_000, b'4'),
        (250_000, b'5'), (500_000, b'6'), (750_000, b'7'), (1_000_000, b'8'), (83_300, b'9'),
    ];
    let code = CODES.iter().find(|(rate, _)| *rate == bitrate).map(|c| c.1);
    let code = code.ok_or_else(|| format!("slcan has no code for bit rate {bitrate} (10k, 20k, 50k, 83.3k, 100k, 125k, 250k, 500k, 750k, 1M)"))?;
    Ok(vec![b'S', code, b'\r'])
}

/// The bytes the host writes to open the channel: close, bit rate, open.
pub fn open_sequence(bitrate: Option<u32>) -> Result<Vec<u8>, String> {
    let mut out = b"C\r".to_vec();
    if let Some(rate) = bitrate {
        out.extend(bitrate_command(rate)?);
    }
    out.extend_from_slice(b"O\r");
    Ok(out)
}

pub const CLOSE: &[u8] = b"C\r";

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    pub id: u32,
    pub extended: bool,
    pub remote: bool,
    pub len: usize,
    pub data: [u8; 8],
}

/// The decoder's counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SlcanStats {
    pub lines: u64,
    pub undecodable_frames: u64,
    pub refused_commands: u64,
}

#[derive(Debug, Default)]
pub struct LineDecoder {
    line: Vec<u8>,
    overflow: bool,
    pub stats: SlcanStats,
}

impl LineDecoder {
    /// Feed adapter bytes in any cut; `out` gets each received frame in order.
    pub fn feed(&mut self, data: &[u8], mut out: impl FnMut(CanFrame)) {
        for &b in data {
            match b {
                b'\r' | b'\n' => self.end_line(&mut out),
                BEL => {
                    self.stats.refused_commands += 1;
                    self.line.clear();
                }
                _ if self.line.len() < MAX_LINE => self.line.push(b),
                _ => self.overflow = true,
            }
        }
    }

    fn end_line(&mut self, out: &mut impl FnMut(CanFrame)) {
        if self.overflow {
            self.stats.undecodable_frames += 1;
        } else if !self.line.is_empty() {
            self.stats.lines += 1;
            match self.line[0] {
                b't' | b'T' | b'r' | b'R' => match decode_frame(&self.line) {
                    Some(frame) => out(frame),
                    None => self.stats.undecodable_frames += 1,
                },
                // Command answers (z/Z transmitted, V/N/F replies): nothing to do.
                b'z' | b'Z' | b'V' | b'N' | b'F' => {}
                _ => self.stats.undecodable_frames += 1,
            }
        }
        self.line.clear();
        self.overflow = false;
    }

    pub fn reset(&mut self) {
        self.line.clear();
        self.overflow = false;
    }
}

fn hex(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() || digits.len() > 8 {
        return None;
    }
    digits.iter().try_fold(0u32, |acc, &d| Some(acc << 4 | (d as char).to_digit(16)?))
}

/// One `t`/`T`/`r`/`R` line without its CR; None when malformed.
pub fn decode_frame(line: &[u8]) -> Option<CanFrame> {
    let (id_digits, extended, remote) = match *line.first()? {
        b't' => (3, false, false),
        b'T' => (8, true, false),
        b'r' => (3, false, true),
        b'R' => (8, true, true),
        _ => return None,
    };
    let id = hex(line.get(1..1 + id_digits)?)?;
    if id > if extended { 0x1FFF_FFFF } else { 0x7FF } {
        return None;
    }
    let len = (*line.get(1 + id_digits)? as char).to_digit(10)? as usize;
    if len > 8 {
        return None;
    }
    let rest = &line[2 + id_digits..];
    let data_digits = if remote { 0 } else { 2 * len };
    // Data, then nothing or a 4-digit timestamp.
    if rest.len() != data_digits && rest.len() != data_digits + 4 {
        return None;
    }
    if rest.len() == data_digits + 4 {
        hex(&rest[data_digits..])?;
    }
    let mut data = [0u8; 8];
    for (k, byte) in data.iter_mut().take(if remote { 0 } else { len }).enumerate() {
        *byte = hex(&rest[2 * k..2 * k + 2])? as u8;
    }
    Some(CanFrame { id, extended, remote, len, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(d: &mut LineDecoder, data: &[u8]) -> Vec<CanFrame> {
        let mut out = Vec::new();
        d.feed(data, |f| out.push(f));
        out
    }

    #[test]
    fn data_frames_with_and_without_timestamps_decode() {
        let mut d = LineDecoder::default();
        let got = frames(&mut d, b"\rt1008AA07080A00010000\rT01ABCDEF2BEEF1234\rz\r");
        assert_eq!(got.len(), 2);
        assert_eq!((got[0].id, got[0].len, got[0].data[0], got[0].extended), (0x100, 8, 0xAA, false));
        assert_eq!((got[1].id, got[1].len, &got[1].data[..2], got[1].extended), (0x1ABCDEF, 2, &[0xBE, 0xEF][..], true));
        assert_eq!(d.stats.undecodable_frames, 0);
    }

    #[test]
    fn malformed_lines_and_bells_are_counted_not_decoded() {
        let mut d = LineDecoder::default();
        for line in [&b"t1009AA\r"[..], b"t10X2AABB\r", b"tFFF1AA\r", b"t1002AAB\r", b"\xff\xfe\r", b"t1002AABB12\r"] {
            assert!(frames(&mut d, line).is_empty(), "{line:?}");
        }
        frames(&mut d, b"\x07");
        assert_eq!((d.stats.undecodable_frames, d.stats.refused_commands), (6, 1));
        let mut long = vec![b't'; 500];
        long.push(b'\r');
        assert!(frames(&mut d, &long).is_empty());
        assert_eq!(d.stats.undecodable_frames, 7);
        assert_eq!(frames(&mut d, b"t1001AA\r").len(), 1, "the next line decodes again");
    }

    #[test]
    fn the_open_sequence_is_close_bitrate_open() {
        assert_eq!(open_sequence(Some(1_000_000)).unwrap(), b"C\rS8\rO\r");
        assert_eq!(open_sequence(None).unwrap(), b"C\rO\r");
        assert!(open_sequence(Some(1_234)).is_err());
    }
}
