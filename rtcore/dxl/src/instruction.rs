//! Instruction codes. Both protocols share the numbering for the instructions they have in
//! common, so one set of constants serves P1 and P2 (P1 lacks REBOOT, SYNC_READ and the rest).

pub const PING: u8 = 0x01;
pub const READ: u8 = 0x02;
pub const WRITE: u8 = 0x03;
pub const REG_WRITE: u8 = 0x04;
pub const ACTION: u8 = 0x05;
pub const FACTORY_RESET: u8 = 0x06;
pub const REBOOT: u8 = 0x08;
pub const CLEAR: u8 = 0x10;
pub const CONTROL_TABLE_BACKUP: u8 = 0x20;
pub const STATUS: u8 = 0x55;
pub const SYNC_READ: u8 = 0x82;
pub const SYNC_WRITE: u8 = 0x83;
pub const FAST_SYNC_READ: u8 = 0x8A;
pub const BULK_READ: u8 = 0x92;
pub const BULK_WRITE: u8 = 0x93;
pub const FAST_BULK_READ: u8 = 0x9A;

/// The e-manual name of an instruction code, for messages and logs.
pub fn name(code: u8) -> Option<&'static str> {
    Some(match code {
        PING => "PING",
        READ => "READ",
        WRITE => "WRITE",
        REG_WRITE => "REG_WRITE",
        ACTION => "ACTION",
        FACTORY_RESET => "FACTORY_RESET",
        REBOOT => "REBOOT",
        CLEAR => "CLEAR",
        CONTROL_TABLE_BACKUP => "CONTROL_TABLE_BACKUP",
        STATUS => "STATUS",
        SYNC_READ => "SYNC_READ",
        SYNC_WRITE => "SYNC_WRITE",
        FAST_SYNC_READ => "FAST_SYNC_READ",
        BULK_READ => "BULK_READ",
        BULK_WRITE => "BULK_WRITE",
        FAST_BULK_READ => "FAST_BULK_READ",
        _ => return None,
    })
}
