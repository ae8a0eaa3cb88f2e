//! The P2 status error byte: bit 7 is the hardware alert, bits 6..0 an error *number*
//! (not a bitfield, unlike P1), decoded to a typed code.
use core::fmt;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorCode {
    ResultFail,
    Instruction,
    Crc,
    DataRange,
    DataLength,
    DataLimit,
    Access,
    /// A number the e-manual does not define (kept, not dropped).
    Other(u8),
}

impl ErrorCode {
    pub fn from_number(n: u8) -> Option<ErrorCode> {
        Some(match n {
            0 => return None,
            1 => ErrorCode::ResultFail,
            2 => ErrorCode::Instruction,
            3 => ErrorCode::Crc,
            4 => ErrorCode::DataRange,
            5 => ErrorCode::DataLength,
            6 => ErrorCode::DataLimit,
            7 => ErrorCode::Access,
            n => ErrorCode::Other(n),
        })
    }

    pub fn number(self) -> u8 {
        match self {
            ErrorCode::ResultFail => 1,
            ErrorCode::Instruction => 2,
            ErrorCode::Crc => 3,
            ErrorCode::DataRange => 4,
            ErrorCode::DataLength => 5,
            ErrorCode::DataLimit => 6,
            ErrorCode::Access => 7,
            ErrorCode::Other(n) => n & 0x7F,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ErrorCode::ResultFail => "Result Fail",
            ErrorCode::Instruction => "Instruction Error",
            ErrorCode::Crc => "CRC Error",
            ErrorCode::DataRange => "Data Range Error",
            ErrorCode::DataLength => "Data Length Error",
            ErrorCode::DataLimit => "Data Limit Error",
            ErrorCode::Access => "Access Error",
            ErrorCode::Other(_) => "Unknown Error",
        }
    }
}

/// The decoded error byte of a P2 status packet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StatusError {
    /// Bit 7: a hardware problem; read Hardware Error Status (address 70) for the cause.
    pub alert: bool,
    /// Bits 6..0: why the instruction failed, `None` when it succeeded.
    pub code: Option<ErrorCode>,
}

impl StatusError {
    pub const OK: StatusError = StatusError { alert: false, code: None };

    pub fn from_raw(raw: u8) -> StatusError {
        StatusError { alert: raw & 0x80 != 0, code: ErrorCode::from_number(raw & 0x7F) }
    }

    pub fn raw(self) -> u8 {
        (if self.alert { 0x80 } else { 0 }) | self.code.map_or(0, ErrorCode::number)
    }
}

impl fmt::Display for StatusError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.code {
            Some(c) => write!(f, "{} (0x{:02X})", c.name(), c.number())?,
            None => write!(f, "no error")?,
        }
        if self.alert {
            write!(f, ", hardware alert")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_byte_round_trips() {
        for raw in 0..=255u8 {
            assert_eq!(StatusError::from_raw(raw).raw(), raw);
        }
    }

    #[test]
    fn alert_and_access_error() {
        let e = StatusError::from_raw(0x87);
        assert!(e.alert);
        assert_eq!(e.code, Some(ErrorCode::Access));
    }
}
