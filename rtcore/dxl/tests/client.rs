//! The client against a scripted bus (tests/common): every request and reply path of both
//! protocols, missing servos, servo errors and line noise.
mod common;

use std::time::Duration;

use common::FakeBus;
use dxl::client::{Client, ClientError, PingInfo, Slot};
use dxl::packet::{BulkEntry, Protocol, ServoError};
use dxl::protocol2::{ErrorCode, StatusError};

fn client(protocol: Protocol, ids: &[u8]) -> Client<FakeBus> {
    Client::new(FakeBus::new(protocol, ids, if protocol == Protocol::V2 { 311 } else { 310 }), protocol, Duration::from_millis(1))
}

#[test]
fn ping_reports_model_and_firmware() {
    assert_eq!(client(Protocol::V2, &[1]).ping(1).unwrap(), PingInfo { model_number: 311, firmware: Some(45) });
    assert_eq!(client(Protocol::V1, &[1]).ping(1).unwrap(), PingInfo { model_number: 310, firmware: None });
}

#[test]
fn write_then_read_back_both_protocols() {
    for protocol in [Protocol::V1, Protocol::V2] {
        let mut c = client(protocol, &[3]);
        assert_eq!(c.write(3, 116, &[1, 2, 3, 4]).unwrap().map(ServoError::alert), Some(false));
        let mut out = [0u8; 4];
        c.read(3, 116, &mut out).unwrap();
        assert_eq!(out, [1, 2, 3, 4]);
    }
}

#[test]
fn sync_write_then_sync_read_in_listed_order() {
    let mut c = client(Protocol::V2, &[1, 2, 7]);
    let data = [10, 0, 0, 0, 20, 0, 0, 0, 70, 0, 0, 0];
    c.sync_write(116, 4, &[1, 2, 7], &data).unwrap();
    let mut out = [0u8; 12];
    let mut slots = [Slot::Missing; 3];
    assert_eq!(c.sync_read(116, 4, &[7, 1, 2], &mut out, &mut slots).unwrap(), 3);
    assert_eq!(out, [70, 0, 0, 0, 10, 0, 0, 0, 20, 0, 0, 0]);
    assert!(slots.iter().all(|s| matches!(s, Slot::Received(_))));
}

#[test]
fn a_missing_servo_leaves_its_slot_missing() {
    let mut c = client(Protocol::V2, &[1, 2]);
    let mut out = [0u8; 6];
    let mut slots = [Slot::Missing; 3];
    assert_eq!(c.sync_read(0, 2, &[1, 9, 2], &mut out, &mut slots).unwrap(), 2);
    assert_eq!(slots[1], Slot::Missing);
    assert_eq!((&out[..2], &out[4..]), (&[0x37, 0x01][..], &[0x37, 0x01][..]));
}

#[test]
fn bulk_read_both_protocols() {
    for protocol in [Protocol::V1, Protocol::V2] {
        let mut c = client(protocol, &[1, 2]);
        c.write(1, 30, &[0xAA, 0xBB]).unwrap();
        c.write(2, 40, &[0xCC]).unwrap();
        let entries = [BulkEntry { id: 1, address: 30, length: 2 }, BulkEntry { id: 2, address: 40, length: 1 }];
        let mut out = [0u8; 3];
        let mut slots = [Slot::Missing; 2];
        assert_eq!(c.bulk_read(&entries, &mut out, &mut slots).unwrap(), 2);
        assert_eq!(out, [0xAA, 0xBB, 0xCC]);
    }
}

#[test]
fn servo_errors_are_typed() {
    let mut c = client(Protocol::V2, &[4]);
    c.transport_mut().servos[0].error = 0x07;
    match c.write(4, 0, &[1]) {
        Err(ClientError::Servo { id: 4, error: ServoError::V2(StatusError { code: Some(ErrorCode::Access), .. }) }) => {}
        other => panic!("expected an Access Error, got {other:?}"),
    }
    c.transport_mut().servos[0].error = 0x80;
    assert_eq!(c.write(4, 64, &[1]).unwrap().map(ServoError::alert), Some(true), "alert alone is not a failure");
}

#[test]
fn silence_is_a_timeout_naming_the_servo() {
    let mut c = client(Protocol::V2, &[1]);
    let err = c.ping(5).unwrap_err();
    assert!(matches!(err, ClientError::Timeout { id: 5, .. }), "{err}");
    assert_eq!(err.to_string(), "no reply from servo 5 before the deadline");
}

#[test]
fn noise_before_each_reply_is_skipped() {
    let mut c = client(Protocol::V2, &[1, 2]);
    c.transport_mut().noise = &[0x00, 0xFF, 0xFF, 0xFD, 0x13, 0xFF];
    let mut out = [0u8; 4];
    let mut slots = [Slot::Missing; 2];
    assert_eq!(c.sync_read(0, 2, &[1, 2], &mut out, &mut slots).unwrap(), 2);
}

#[test]
fn protocol_1_refuses_what_it_lacks() {
    let mut c = client(Protocol::V1, &[1]);
    assert!(matches!(c.reboot(1), Err(ClientError::Unsupported { instruction: "REBOOT", .. })));
    assert!(matches!(c.read(1, 300, &mut [0u8; 2]), Err(ClientError::Encode(_))));
}

#[test]
fn a_late_reply_after_a_timeout_is_not_taken_for_the_next_one() {
    let mut c = client(Protocol::V2, &[1]);
    assert!(c.ping(5).is_err());
    let mut stale = [0u8; 16];
    let n = dxl::protocol2::encode_status(&mut stale, 1, 0, &[9, 9]).unwrap();
    c.transport_mut().inject(&stale[..n]);
    let mut out = [0xEEu8; 2];
    c.read(1, 36, &mut out).unwrap();
    assert_eq!(out, [0, 0], "the stale [9, 9] must be drained, not returned");
}
