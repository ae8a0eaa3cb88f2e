//! CRC-16 of Dynamixel Protocol 2.0: polynomial 0x8005, MSB-first, init 0, no reflection,
//! no final XOR (catalogue name CRC-16/BUYPASS; check value of "123456789" is 0xFEE8).
//!
//! A 256-entry table built at compile time: one lookup per byte keeps the per-cycle cost of a
//! SyncWrite negligible without any runtime initialisation (no lazy statics on the RT path).

const POLY: u16 = 0x8005;

const TABLE: [u16; 256] = build_table();

const fn build_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ POLY } else { crc << 1 };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
}

/// Continue a CRC over more bytes (start with 0 for a new packet).
pub fn crc16_update(mut crc: u16, bytes: &[u8]) -> u16 {
    for &b in bytes {
        let i = ((crc >> 8) as u8 ^ b) as usize;
        crc = (crc << 8) ^ TABLE[i];
    }
    crc
}

/// CRC-16 of a byte slice (as covered on the wire: header through the last, stuffed, parameter).
pub fn crc16(bytes: &[u8]) -> u16 {
    crc16_update(0, bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn catalogue_check_value() {
        assert_eq!(crc16(b"123456789"), 0xFEE8);
    }

    #[test]
    fn table_matches_the_sdk_endpoints() {
        assert_eq!(TABLE[1], 0x8005);
        assert_eq!(TABLE[255], 0x0202);
    }

    #[test]
    fn update_is_incremental() {
        let data = b"FF FF FD arbitrary split";
        let (a, b) = data.split_at(7);
        assert_eq!(crc16_update(crc16(a), b), crc16(data));
    }
}
