//! The OptoForce / OnRobot OMD "General DAQ" wire format, as `admittance/drivers/optoforce.py`
//! parses it (shared protocols.md §5.1): fixed-size big-endian frames that start with 0xAA and
//! end in the 16-bit sum of every preceding byte; bytes 1..3 of the header name the frame type.
//!
//! Why a search-and-verify parser: the stream is not aligned (7-byte acknowledgements between
//! samples, a read may cut a frame anywhere, a reader may join mid-frame), so every candidate
//! header is checked by its checksum and a failed candidate skips exactly one byte, so that a
//! real frame hiding inside a false one is still found. The Python parser is the reference:
//! the same counters, the same frame table (tests in `tests/test_rust_sensor.py` feed both).

pub const HEADER_BYTE: u8 = 0xAA;
const HEADER_SIZE: usize = 4;
const CHECKSUM_SIZE: usize = 2;
/// Held-back bytes beyond this are garbage by construction (no frame is longer): a stream
/// that never syncs cannot grow the buffer.
const MAX_PENDING: usize = 4096;

pub const STATUS_DAQ_ERROR_MASK: u16 = 0xE000;
pub const STATUS_SENSOR_ERROR_MASK: u16 = 0x1C00;
pub const STATUS_FAULT_MASK: u16 = STATUS_DAQ_ERROR_MASK | STATUS_SENSOR_ERROR_MASK;
/// Overload flags, bit 9 (fx) down to bit 4 (tz).
pub const STATUS_OVERLOAD_MASK: u16 = 0b11_1111 << 4;
const OVERLOAD_AXES: [&str; 6] = ["fx", "fy", "fz", "tx", "ty", "tz"];

/// SPEED code = sample period in ms; FILTER code = cut-off; ZERO 255 = tare in the DAQ.
pub const RATE_CODES: [(u32, u8); 6] = [(0, 0), (1000, 1), (333, 3), (100, 10), (30, 33), (10, 100)];
pub const FILTER_CODES: [(f64, u8); 7] = [(0.0, 0), (500.0, 1), (150.0, 2), (50.0, 3), (15.0, 4), (5.0, 5), (1.5, 6)];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Sample3,
    Sample6,
    Sample12,
    Ack,
    Config,
    SerialNumber,
}

/// (header, frame size, kind): the one table the decoder and the encoders share.
const FRAME_KINDS: [([u8; 4], usize, Kind); 6] = [
    ([0xAA, 0x07, 0x08, 0x0A], 16, Kind::Sample3),
    ([0xAA, 0x07, 0x08, 0x10], 22, Kind::Sample6),
    ([0xAA, 0x07, 0x08, 0x1C], 34, Kind::Sample12),
    ([0xAA, 0x00, 0x50, 0x01], 7, Kind::Ack),
    ([0xAA, 0x00, 0x32, 0x03], 9, Kind::Config),
    ([0xAA, 0x00, 0x12, 0x08], 14, Kind::SerialNumber),
];

/// One decoded sample frame: raw counts (3, 6 or 12 of them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sample {
    pub counter: u16,
    pub status: u16,
    pub counts: [i16; 12],
    pub n: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Record {
    Sample(Sample),
    Ack(u8),
    /// A host's configuration packet (raw codes: `RATE_CODES`, `FILTER_CODES`, zero 255 = tare,
    /// 0 = clear the tare): what the simulated DAQ answers.
    Config { speed: u8, filter: u8, zero: u8 },
    Other,
}

pub fn checksum(data: &[u8]) -> u16 {
    data.iter().fold(0u16, |acc, &b| acc.wrapping_add(b as u16))
}

fn seal(mut frame: Vec<u8>) -> Vec<u8> {
    let sum = checksum(&frame);
    frame.extend_from_slice(&sum.to_be_bytes());
    frame
}

/// A sample frame (the simulated sensor's side, for tests); `counts` has 3, 6 or 12 values.
pub fn encode_sample(counter: u16, status: u16, counts: &[i16]) -> Option<Vec<u8>> {
    let header = FRAME_KINDS.iter().find(|(_, size, _)| (size - 10) / 2 == counts.len())?.0;
    let mut frame = header.to_vec();
    frame.extend_from_slice(&counter.to_be_bytes());
    frame.extend_from_slice(&status.to_be_bytes());
    for c in counts {
        frame.extend_from_slice(&c.to_be_bytes());
    }
    Some(seal(frame))
}

pub fn encode_ack(code: u8) -> Vec<u8> {
    seal(vec![0xAA, 0x00, 0x50, 0x01, code])
}

/// The host's configuration packet, from a rate (Hz), a filter cut-off (Hz) and the tare flag;
/// `Err` names the values the DAQ accepts.
pub fn config_packet(rate_hz: u32, filter_hz: f64, tare: bool) -> Result<Vec<u8>, String> {
    let speed = RATE_CODES.iter().find(|(hz, _)| *hz == rate_hz).map(|c| c.1);
    let speed = speed.ok_or_else(|| format!("OptoForce rate {rate_hz} Hz is not one of [0, 10, 30, 100, 333, 1000]"))?;
    let filter = FILTER_CODES.iter().find(|(hz, _)| *hz == filter_hz).map(|c| c.1);
    let filter = filter.ok_or_else(|| format!("OptoForce filter {filter_hz} Hz is not one of [0, 1.5, 5, 15, 50, 150, 500]"))?;
    Ok(seal(vec![0xAA, 0x00, 0x32, 0x03, speed, filter, if tare { 255 } else { 0 }]))
}

/// The parser's counters, named as the Python parser's `stats()`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ParserStats {
    pub frames: u64,
    pub samples: u64,
    pub acks: u64,
    pub checksum_errors: u64,
    pub resyncs: u64,
    pub skipped_bytes: u64,
}

/// Feed it bytes in any cut; it hands back whole, checksum-valid records.
#[derive(Debug, Default)]
pub struct Parser {
    buf: Vec<u8>,
    skipping: bool,
    pub stats: ParserStats,
}

impl Parser {
    /// Parse `data` (after whatever was held back), calling `out` for each record in order.
    pub fn feed(&mut self, data: &[u8], mut out: impl FnMut(Record)) {
        self.buf.extend_from_slice(data);
        let mut pos = 0;
        let end = self.buf.len();
        while end - pos >= HEADER_SIZE {
            if self.buf[pos] != HEADER_BYTE {
                let start = self.buf[pos..].iter().position(|&b| b == HEADER_BYTE).map_or(end, |i| pos + i);
                self.skip(start - pos);
                pos = start;
                continue;
            }
            let Some(&(_, size, kind)) = FRAME_KINDS.iter().find(|(h, _, _)| self.buf[pos..pos + HEADER_SIZE] == *h) else {
                self.skip(1);
                pos += 1;
                continue;
            };
            let stop = pos + size;
            if stop > end {
                break;
            }
            let frame = &self.buf[pos..stop];
            let stated = u16::from_be_bytes([frame[size - 2], frame[size - 1]]);
            if checksum(&frame[..size - CHECKSUM_SIZE]) != stated {
                self.stats.checksum_errors += 1;
                self.skip(1);
                pos += 1;
                continue;
            }
            let record = decode(kind, frame);
            self.count(&record);
            out(record);
            self.skipping = false;
            pos = stop;
        }
        // A short tail keeps only what may start a frame.
        let start = self.buf[pos..].iter().position(|&b| b == HEADER_BYTE).map_or(end, |i| pos + i);
        if start > pos {
            self.skip(start - pos);
            pos = start;
        }
        if end - pos > MAX_PENDING {
            self.skip(end - pos);
            pos = end;
        }
        self.buf.drain(..pos);
    }

    fn count(&mut self, record: &Record) {
        self.stats.frames += 1;
        match record {
            Record::Sample(_) => self.stats.samples += 1,
            Record::Ack(_) => self.stats.acks += 1,
            Record::Config { .. } | Record::Other => {}
        }
    }

    fn skip(&mut self, n: usize) {
        if !self.skipping {
            self.stats.resyncs += 1;
            self.skipping = true;
        }
        self.stats.skipped_bytes += n as u64;
    }

    /// Bytes held back waiting for the rest of a frame.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// Forget held-back bytes (a reopened device starts a new stream).
    pub fn reset(&mut self) {
        self.buf.clear();
        self.skipping = false;
    }
}

fn decode(kind: Kind, frame: &[u8]) -> Record {
    let word = |i: usize| u16::from_be_bytes([frame[i], frame[i + 1]]);
    match kind {
        Kind::Sample3 | Kind::Sample6 | Kind::Sample12 => {
            let n = (frame.len() - 10) / 2;
            let mut counts = [0i16; 12];
            for (k, c) in counts.iter_mut().take(n).enumerate() {
                *c = word(8 + 2 * k) as i16;
            }
            Record::Sample(Sample { counter: word(4), status: word(6), counts, n })
        }
        Kind::Ack => Record::Ack(frame[4]),
        Kind::Config => Record::Config { speed: frame[4], filter: frame[5], zero: frame[6] },
        Kind::SerialNumber => Record::Other,
    }
}

/// What a sample became.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Converted {
    /// Forces [fx, fy, fz, tx, ty, tz] in N and N·m (bias not yet removed).
    Force([f64; 6]),
    /// Saturated and handed on under `saturation = "pass"` (the caller tells it).
    SaturatedForce([f64; 6]),
    /// Not handed on: a DAQ/sensor fault, the wrong frame type, or saturated under "hold".
    Held(HeldWhy),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeldWhy {
    StatusFault,
    Saturated,
    UnexpectedFrame,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Saturation {
    Hold,
    Pass,
}

impl Saturation {
    pub fn parse(text: &str) -> Result<Self, String> {
        match text {
            "hold" => Ok(Saturation::Hold),
            "pass" => Ok(Saturation::Pass),
            other => Err(format!("saturation must be one of hold, pass, not {other:?}")),
        }
    }
}

/// The converter's counters, named as the Python `SampleConverter.stats()`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ConverterStats {
    pub status_faults: u64,
    pub overloads: u64,
    pub unexpected_frames: u64,
    pub counter_gaps: u64,
    pub ack_errors: u64,
    pub last_fault_status: u16,
    pub last_overload_status: u16,
}

/// Counts → newtons with the calibration sheet's per-axis sensitivities, and the policies:
/// a faulty status word never reaches the loop; a saturated sample (an overload flag, or a
/// count at the int16 limit) is held or passed as configured.
#[derive(Debug)]
pub struct Converter {
    axes: usize,
    sensor_index: usize,
    scale: [f64; 6],
    saturation: Saturation,
    last_counter: Option<u16>,
    pub stats: ConverterStats,
}

impl Converter {
    /// `counts_per_unit`: one positive, finite value per axis (3 or 6); `sensor_index` picks
    /// one of a 4-channel DAQ's 3-axis sensors.
    pub fn new(counts_per_unit: &[f64], axes: usize, sensor_index: usize, saturation: Saturation) -> Result<Self, String> {
        if axes != 3 && axes != 6 {
            return Err(format!("an OptoForce sensor has 3 or 6 axes, not {axes}"));
        }
        if sensor_index > 3 || (axes == 6 && sensor_index != 0) {
            return Err(format!("sensor_index {sensor_index} is out of range (0..3, and 0 for a 6-axis sensor)"));
        }
        if counts_per_unit.len() != axes {
            return Err(format!("counts_per_newton needs {axes} values (one per axis), got {}", counts_per_unit.len()));
        }
        if counts_per_unit.iter().any(|c| !c.is_finite() || *c <= 0.0) {
            return Err(format!("counts_per_newton must be positive and finite, got {counts_per_unit:?}"));
        }
        let mut scale = [0.0; 6];
        for (s, c) in scale.iter_mut().zip(counts_per_unit) {
            *s = 1.0 / c;
        }
        Ok(Converter { axes, sensor_index, scale, saturation, last_counter: None, stats: ConverterStats::default() })
    }

    pub fn convert(&mut self, sample: &Sample) -> Converted {
        self.track_counter(sample.counter);
        if sample.status & STATUS_FAULT_MASK != 0 {
            self.stats.status_faults += 1;
            self.stats.last_fault_status = sample.status;
            return Converted::Held(HeldWhy::StatusFault);
        }
        let counts: &[i16] = if sample.n == 12 {
            &sample.counts[3 * self.sensor_index..3 * self.sensor_index + 3]
        } else {
            &sample.counts[..sample.n.min(12)]
        };
        if (counts.len() == 6) != (self.axes == 6) {
            self.stats.unexpected_frames += 1;
            return Converted::Held(HeldWhy::UnexpectedFrame);
        }
        let saturated = sample.status & STATUS_OVERLOAD_MASK != 0 || counts.iter().any(|&c| c == i16::MIN || c == -32767 || c == i16::MAX);
        let mut forces = [0.0; 6];
        for ((f, &c), s) in forces.iter_mut().zip(counts).zip(self.scale) {
            *f = c as f64 * s;
        }
        if !saturated {
            return Converted::Force(forces);
        }
        self.stats.overloads += 1;
        self.stats.last_overload_status = sample.status;
        match self.saturation {
            Saturation::Hold => Converted::Held(HeldWhy::Saturated),
            Saturation::Pass => Converted::SaturatedForce(forces),
        }
    }

    fn track_counter(&mut self, counter: u16) {
        if let Some(last) = self.last_counter {
            if counter != last.wrapping_add(1) {
                self.stats.counter_gaps += 1;
            }
        }
        self.last_counter = Some(counter);
    }

    /// The last saturated sample in words, with what the policy did with it (the Python text).
    pub fn saturation_note(&self) -> String {
        let status = self.stats.last_overload_status;
        let axes: Vec<&str> = OVERLOAD_AXES.iter().enumerate().filter(|(i, _)| status & (1 << (9 - i)) != 0).map(|(_, a)| *a).collect();
        let what = if axes.is_empty() { "a count at the int16 limit".to_string() } else { format!("overload flag on {}", axes.join(", ")) };
        let action = match self.saturation {
            Saturation::Hold => "held, not passed to the loop",
            Saturation::Pass => "passed on (saturation = \"pass\")",
        };
        format!("saturated samples ({what}): {action}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(p: &mut Parser, data: &[u8]) -> Vec<Record> {
        let mut out = Vec::new();
        p.feed(data, |r| out.push(r));
        out
    }

    #[test]
    fn a_frame_cut_anywhere_is_decoded_once() {
        let frame = encode_sample(7, 0, &[100, -200, 300]).unwrap();
        for cut in 0..frame.len() {
            let mut p = Parser::default();
            let mut got = parse(&mut p, &frame[..cut]);
            got.extend(parse(&mut p, &frame[cut..]));
            assert_eq!(got.len(), 1, "cut at {cut}");
            let Record::Sample(s) = got[0] else { panic!("not a sample") };
            assert_eq!((s.counter, s.n, &s.counts[..3]), (7, 3, &[100, -200, 300][..]));
        }
    }

    #[test]
    fn garbage_and_a_bad_checksum_are_skipped_and_counted() {
        let good = encode_sample(1, 0, &[1, 2, 3]).unwrap();
        let mut bad = encode_sample(2, 0, &[4, 5, 6]).unwrap();
        bad[9] ^= 0x40;
        let mut stream = vec![0x00, 0x13, 0xAA, 0x55];
        stream.extend(&bad);
        stream.extend(&good);
        stream.extend(encode_ack(0));
        let mut p = Parser::default();
        let got = parse(&mut p, &stream);
        assert_eq!(got.len(), 2);
        assert_eq!(p.stats.checksum_errors, 1);
        assert_eq!((p.stats.samples, p.stats.acks), (1, 1));
        assert!(p.stats.skipped_bytes >= 4 + bad.len() as u64 && p.stats.resyncs >= 1);
    }

    #[test]
    fn a_stream_that_never_syncs_keeps_a_bounded_buffer() {
        let mut p = Parser::default();
        let mut noise = vec![0xAA, 0x07, 0x08, 0x1C];
        noise.resize(34 - 1, 0x11); // a 4-channel header whose frame never completes...
        for _ in 0..500 {
            parse(&mut p, &[0xAA; 64]);
        }
        parse(&mut p, &noise);
        assert!(p.pending() <= MAX_PENDING + 64);
    }

    #[test]
    fn counts_become_newtons_and_the_policies_hold() {
        let mut c = Converter::new(&[100.0, 100.0, 50.0], 3, 0, Saturation::Hold).unwrap();
        let s = |status, counts: [i16; 3]| {
            let mut all = [0; 12];
            all[..3].copy_from_slice(&counts);
            Sample { counter: 0, status, counts: all, n: 3 }
        };
        assert_eq!(c.convert(&s(0, [100, -50, 100])), Converted::Force([1.0, -0.5, 2.0, 0.0, 0.0, 0.0]));
        assert_eq!(c.convert(&s(0x2000, [1, 1, 1])), Converted::Held(HeldWhy::StatusFault));
        assert_eq!(c.convert(&s(1 << 9, [1, 1, 1])), Converted::Held(HeldWhy::Saturated));
        assert_eq!(c.convert(&s(0, [i16::MAX, 0, 0])), Converted::Held(HeldWhy::Saturated));
        assert!(c.saturation_note().contains("int16 limit"));
        assert_eq!((c.stats.status_faults, c.stats.overloads), (1, 2));
        let mut pass = Converter::new(&[100.0; 3], 3, 0, Saturation::Pass).unwrap();
        assert!(matches!(pass.convert(&s(1 << 8, [1, 1, 1])), Converted::SaturatedForce(_)));
        assert!(pass.saturation_note().contains("overload flag on fy"));
    }

    #[test]
    fn counter_gaps_and_wrong_frame_types_are_counted() {
        let mut c = Converter::new(&[1.0; 3], 3, 0, Saturation::Hold).unwrap();
        let mut s = Sample { counter: 65535, status: 0, counts: [0; 12], n: 3 };
        c.convert(&s);
        s.counter = 0; // wraps: no gap
        c.convert(&s);
        s.counter = 5;
        c.convert(&s);
        s.n = 6;
        assert_eq!(c.convert(&s), Converted::Held(HeldWhy::UnexpectedFrame));
        assert_eq!((c.stats.counter_gaps, c.stats.unexpected_frames), (2, 1));
    }

    #[test]
    fn a_four_channel_frame_yields_the_chosen_sensor() {
        let counts: Vec<i16> = (1..=12).collect();
        let frame = encode_sample(0, 0, &counts).unwrap();
        let mut p = Parser::default();
        let Record::Sample(s) = parse(&mut p, &frame)[0] else { panic!() };
        let mut c = Converter::new(&[1.0; 3], 3, 2, Saturation::Hold).unwrap();
        assert_eq!(c.convert(&s), Converted::Force([7.0, 8.0, 9.0, 0.0, 0.0, 0.0]));
    }

    #[test]
    fn the_config_packet_matches_the_python_encoder() {
        // admittance.drivers.optoforce.DaqSettings(1000, 15, True).packet()
        assert_eq!(config_packet(1000, 15.0, true).unwrap(), vec![0xAA, 0x00, 0x32, 0x03, 1, 4, 255, 0x01, 0xE3]);
        assert!(config_packet(500, 0.0, false).is_err());
    }

    #[test]
    fn a_config_packet_parses_back_to_its_codes() {
        let mut p = Parser::default();
        let packet = config_packet(100, 50.0, false).unwrap();
        assert_eq!(parse(&mut p, &packet), vec![Record::Config { speed: 10, filter: 3, zero: 0 }]);
    }
}
