//! The P1 status error byte: a bitfield (several faults at once), unlike P2's error number.
use core::fmt;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ErrorBits(pub u8);

impl ErrorBits {
    pub const INPUT_VOLTAGE: u8 = 0x01;
    pub const ANGLE_LIMIT: u8 = 0x02;
    pub const OVERHEATING: u8 = 0x04;
    pub const RANGE: u8 = 0x08;
    pub const CHECKSUM: u8 = 0x10;
    pub const OVERLOAD: u8 = 0x20;
    pub const INSTRUCTION: u8 = 0x40;

    const NAMES: [(u8, &'static str); 7] = [
        (Self::INPUT_VOLTAGE, "Input Voltage"),
        (Self::ANGLE_LIMIT, "Angle Limit"),
        (Self::OVERHEATING, "Overheating"),
        (Self::RANGE, "Range"),
        (Self::CHECKSUM, "Checksum"),
        (Self::OVERLOAD, "Overload"),
        (Self::INSTRUCTION, "Instruction"),
    ];
    const HARDWARE: u8 = Self::INPUT_VOLTAGE | Self::OVERHEATING | Self::OVERLOAD;

    pub fn contains(self, bit: u8) -> bool {
        self.0 & bit != 0
    }

    /// Voltage, overheating or overload: the servo's state, not this instruction's fault.
    pub fn is_hardware(self) -> bool {
        self.0 & Self::HARDWARE != 0
    }

    /// Angle limit, range, checksum or instruction: this instruction was refused.
    pub fn is_instruction_failure(self) -> bool {
        self.0 & !Self::HARDWARE & 0x7F != 0
    }

    /// The names of the bits that are set.
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        Self::NAMES.into_iter().filter(move |(bit, _)| self.contains(*bit)).map(|(_, n)| n)
    }
}

impl fmt::Display for ErrorBits {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 == 0 {
            return write!(f, "no error");
        }
        for (i, name) in self.names().enumerate() {
            write!(f, "{}{name} Error", if i > 0 { ", " } else { "" })?;
        }
        write!(f, " (0x{:02X})", self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overload_and_overheating_example() {
        let e = ErrorBits(0x24);
        assert!(e.contains(ErrorBits::OVERLOAD) && e.contains(ErrorBits::OVERHEATING));
        assert!(e.is_hardware() && !e.is_instruction_failure());
        assert_eq!(e.to_string(), "Overheating Error, Overload Error (0x24)");
    }
}
