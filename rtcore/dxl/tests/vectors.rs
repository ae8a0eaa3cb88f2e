//! Byte-for-byte vectors of the ROBOTIS e-manual (protocols.md §1.5, §2.3–2.4), including the
//! two packets whose printed CRC is wrong in the e-manual (Restore, Fast Bulk Read).
use dxl::packet::{BulkEntry, Kind, ServoError};
use dxl::protocol1::{self as p1, ErrorBits, Expect};
use dxl::protocol2::{self as p2, ErrorCode, StatusError};
use dxl::{crc16, instruction as ins};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

/// Every P2 packet of the e-manual: bytes without the CRC, and the CRC as sent (low, high).
const P2_CRC_VECTORS: &[(&str, &str)] = &[
    ("FF FF FD 00 01 03 00 01", "19 4E"),
    ("FF FF FD 00 01 07 00 55 00 06 04 26", "65 5D"),
    ("FF FF FD 00 FE 03 00 01", "31 42"),
    ("FF FF FD 00 02 07 00 55 00 06 04 26", "6F 6D"),
    ("FF FF FD 00 01 07 00 02 84 00 04 00", "1D 15"),
    ("FF FF FD 00 01 08 00 55 00 A6 00 00 00", "8C C0"),
    ("FF FF FD 00 01 09 00 03 74 00 00 02 00 00", "CA 89"),
    ("FF FF FD 00 01 04 00 55 00", "A1 0C"),
    ("FF FF FD 00 01 09 00 04 68 00 C8 00 00 00", "AE 8E"),
    ("FF FF FD 00 01 03 00 05", "02 CE"),
    ("FF FF FD 00 01 04 00 06 01", "A1 E6"),
    ("FF FF FD 00 01 03 00 08", "2F 4E"),
    ("FF FF FD 00 01 08 00 10 01 44 58 4C 22", "B1 DC"),
    ("FF FF FD 00 01 08 00 20 01 43 54 52 4C", "16 F5"),
    // DOC ERROR: the e-manual prints 92 F5.
    ("FF FF FD 00 01 08 00 20 02 43 54 52 4C", "9E F5"),
    ("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02", "CE FA"),
    ("FF FF FD 00 02 08 00 55 00 1F 08 00 00", "BA BE"),
    ("FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00", "82 87"),
    ("FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04", "20 F2"),
    ("FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00", "1A 05"),
    ("FF FF FD 00 01 06 00 55 00 77 00", "C3 69"),
    ("FF FF FD 00 02 05 00 55 00 24", "8B A9"),
    ("FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50", "B7 68"),
    // DOC ERROR: the e-manual prints 20 F2 (copied from the Fast Sync Read example).
    ("FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00", "DA 2D"),
];

#[test]
fn catalogue_check_value() {
    assert_eq!(crc16(b"123456789"), 0xFEE8);
}

#[test]
fn every_emanual_crc() {
    for (body, crc) in P2_CRC_VECTORS {
        let c = crc16(&hex(body)).to_le_bytes();
        assert_eq!(c.to_vec(), hex(crc), "packet {body}");
    }
}

/// Every e-manual P2 packet decodes, and its re-encoding is the same bytes.
#[test]
fn every_emanual_packet_decodes_and_re_encodes() {
    for (body, crc) in P2_CRC_VECTORS {
        let wire = [hex(body), hex(crc)].concat();
        let mut d = p2::Decoder::new();
        d.push(&wire);
        let p = d.next().unwrap().unwrap_or_else(|e| panic!("{body}: {e}"));
        let mut buf = [0u8; 64];
        let n = match p.kind {
            Kind::Instruction(code) => p2::encode_instruction(&mut buf, p.id, code, p.params),
            Kind::Status(e) => p2::encode_status(&mut buf, p.id, e.raw(), p.params),
        }
        .unwrap();
        assert_eq!(&buf[..n], &wire[..], "{body}");
    }
}

fn p2(encode: impl FnOnce(&mut [u8]) -> Result<usize, dxl::EncodeError>) -> Vec<u8> {
    let mut buf = [0u8; 128];
    let n = encode(&mut buf).unwrap();
    buf[..n].to_vec()
}

#[test]
fn p2_encoders_match_the_emanual() {
    let full = |i: usize| [hex(P2_CRC_VECTORS[i].0), hex(P2_CRC_VECTORS[i].1)].concat();
    assert_eq!(p2(|b| p2::encode_ping(b, 1)), full(0));
    assert_eq!(p2(|b| p2::encode_status(b, 1, 0, &[0x06, 0x04, 0x26])), full(1));
    assert_eq!(p2(|b| p2::encode_ping(b, 0xFE)), full(2));
    assert_eq!(p2(|b| p2::encode_read(b, 1, 132, 4)), full(4));
    assert_eq!(p2(|b| p2::encode_status(b, 1, 0, &[0xA6, 0, 0, 0])), full(5));
    assert_eq!(p2(|b| p2::encode_write(b, 1, 116, &512u32.to_le_bytes())), full(6));
    assert_eq!(p2(|b| p2::encode_status(b, 1, 0, &[])), full(7));
    assert_eq!(p2(|b| p2::encode_reg_write(b, 1, 104, &200u32.to_le_bytes())), full(8));
    assert_eq!(p2(|b| p2::encode_action(b, 1)), full(9));
    assert_eq!(p2(|b| p2::encode_factory_reset(b, 1, 0x01)), full(10));
    assert_eq!(p2(|b| p2::encode_reboot(b, 1)), full(11));
    assert_eq!(p2(|b| p2::encode_clear(b, 1)), full(12));
    assert_eq!(p2(|b| p2::encode_sync_read(b, 132, 4, &[1, 2])), full(15));
    let data = [150u32.to_le_bytes(), 170u32.to_le_bytes()].concat();
    assert_eq!(p2(|b| p2::encode_sync_write(b, 116, 4, &[1, 2], &data)), full(17));
    let bulk = [BulkEntry { id: 1, address: 144, length: 2 }, BulkEntry { id: 2, address: 146, length: 1 }];
    assert_eq!(p2(|b| p2::encode_bulk_read(b, &bulk)), full(19));
    let bw = [BulkEntry { id: 1, address: 0x20, length: 2 }, BulkEntry { id: 2, address: 0x1F, length: 1 }];
    assert_eq!(p2(|b| p2::encode_bulk_write(b, &bw, &[0xA0, 0x00, 0x50])), full(22));
}

#[test]
fn stuffing_example_of_protocols_md() {
    let got = p2(|b| p2::encode_write(b, 1, 0x74, &[0xFF, 0xFF, 0xFD, 0x00]));
    let mut want = hex("FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD 00");
    want.extend_from_slice(&crc16(&want).to_le_bytes());
    assert_eq!(got, want);
    let mut d = p2::Decoder::new();
    d.push(&got);
    let p = d.next().unwrap().unwrap();
    assert_eq!(p.params, &[0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00]);
}

#[test]
fn status_errors_are_typed() {
    let wire = p2(|b| p2::encode_status(b, 3, 0x87, &[]));
    let mut d = p2::Decoder::new();
    d.push(&wire);
    let p = d.next().unwrap().unwrap();
    assert_eq!(p.kind, Kind::Status(ServoError::V2(StatusError { alert: true, code: Some(ErrorCode::Access) })));
}

#[test]
fn crc_error_reports_both_values() {
    let mut wire = hex("FF FF FD 00 01 03 00 01 19 4F");
    let mut d = p2::Decoder::new();
    d.push(&wire);
    assert_eq!(d.next().unwrap().unwrap_err(), dxl::DecodeError::Crc { id: 1, expected: 0x4E19, actual: 0x4F19 });
    wire[9] = 0x4E;
    d.push(&wire);
    assert!(d.next().unwrap().is_ok(), "the decoder resynchronises after a bad packet");
}

fn p1(encode: impl FnOnce(&mut [u8]) -> Result<usize, dxl::EncodeError>) -> Vec<u8> {
    p2(encode)
}

#[test]
fn p1_encoders_match_the_emanual() {
    assert_eq!(p1(|b| p1::encode_instruction(b, 1, ins::WRITE, &[0x0C, 0x64, 0xAA])), hex("FF FF 01 05 03 0C 64 AA DC"));
    assert_eq!(p1(|b| p1::encode_ping(b, 1)), hex("FF FF 01 02 01 FB"));
    assert_eq!(p1(|b| p1::encode_status(b, 1, 0, &[])), hex("FF FF 01 02 00 FC"));
    assert_eq!(p1(|b| p1::encode_read(b, 1, 43, 1)), hex("FF FF 01 04 02 2B 01 CC"));
    assert_eq!(p1(|b| p1::encode_status(b, 1, 0, &[0x20])), hex("FF FF 01 03 00 20 DB"));
    assert_eq!(p1(|b| p1::encode_write(b, 0xFE, 3, &[1])), hex("FF FF FE 04 03 03 01 F6"));
    assert_eq!(p1(|b| p1::encode_action(b, 0xFE)), hex("FF FF FE 02 05 FA"));
    let data = hex("10 00 50 01 20 02 60 03");
    assert_eq!(
        p1(|b| p1::encode_sync_write(b, 30, 4, &[0, 1], &data)),
        hex("FF FF FE 0E 83 1E 04 00 10 00 50 01 01 20 02 60 03 67")
    );
    let bulk = [BulkEntry { id: 1, address: 0x1E, length: 2 }, BulkEntry { id: 2, address: 0x24, length: 2 }];
    assert_eq!(p1(|b| p1::encode_bulk_read(b, &bulk)), hex("FF FF FE 09 92 00 02 01 1E 02 02 24 1D"));
}

#[test]
fn p1_error_bits_decode() {
    let mut d = p1::Decoder::new(Expect::Status);
    d.push(&hex("FF FF 01 02 24 D8"));
    let p = d.next().unwrap().unwrap();
    let Kind::Status(ServoError::V1(bits)) = p.kind else { panic!("not a status") };
    assert!(bits.contains(ErrorBits::OVERLOAD) && bits.contains(ErrorBits::OVERHEATING));
    assert_eq!(bits.0, 0x24);
}

#[test]
fn p1_checksum_error_reports_both_values() {
    let mut d = p1::Decoder::new(Expect::Instruction);
    d.push(&hex("FF FF 01 02 01 FA"));
    assert_eq!(d.next().unwrap().unwrap_err(), dxl::DecodeError::Checksum { id: 1, expected: 0xFB, actual: 0xFA });
}
