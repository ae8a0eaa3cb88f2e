//! Dynamixel Protocol 1.0: `FF FF | ID | LEN | INST/ERR | params | CHECKSUM`, checksum =
//! !(ID + LEN + INST + params) low byte; no stuffing. Same shape as `protocol2`: encoders into
//! caller buffers and a streaming decoder.
mod decode;
mod encode;
mod status;

pub use decode::{Decoder, Expect};
pub use encode::{
    checksum, encode_action, encode_bulk_read, encode_factory_reset, encode_instruction, encode_instruction_addressed, encode_ping,
    encode_read, encode_reg_write, encode_status, encode_sync_write, encode_write,
};
pub use status::ErrorBits;

pub const HEADER: [u8; 2] = [0xFF, 0xFF];
pub const BROADCAST_ID: u8 = 0xFE;
/// The largest ID of a single device.
pub const MAX_ID: u8 = 0xFD;
/// Bytes before the instruction: header(2) + ID + LEN.
pub const PREFIX_LEN: usize = 4;
/// The largest packet LEN allows: 4 + 255.
pub const MAX_PACKET_LEN: usize = PREFIX_LEN + 255;
/// Size of a status packet with `n` data bytes: 6 + n.
pub const fn status_packet_len(n: usize) -> usize {
    PREFIX_LEN + 2 + n
}
