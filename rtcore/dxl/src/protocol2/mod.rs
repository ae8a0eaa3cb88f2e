//! Dynamixel Protocol 2.0: framing `FF FF FD 00 | ID | LEN_L LEN_H | INST | params | CRC_L CRC_H`,
//! byte stuffing of `FF FF FD` in the instruction..params range, CRC-16/BUYPASS over the
//! stuffed bytes. Encoders write into caller buffers; the decoder streams.
mod decode;
mod fast_sync;
mod encode;
mod status;
pub mod stuffing;

pub use decode::Decoder;
pub use fast_sync::{
    decode_fast_sync_prefix, decode_fast_sync_reply, encode_fast_sync_read, fast_sync_reply_len, fast_sync_reply_prefix, push_fast_sync_segment, FastSyncError,
};
pub use encode::{
    encode_action, encode_addressed, encode_bulk_read, encode_bulk_write, encode_clear, encode_factory_reset,
    encode_instruction, encode_ping, encode_read, encode_reboot, encode_reg_write, encode_status,
    encode_sync_read, encode_sync_write, encode_write, instruction_len, status_len,
};
pub use status::{ErrorCode, StatusError};

pub const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
pub const BROADCAST_ID: u8 = 0xFE;
/// The largest ID of a single device (0xFD and 0xFF are never IDs).
pub const MAX_ID: u8 = 0xFC;
/// Bytes before the instruction: header(4) + ID + length(2).
pub const PREFIX_LEN: usize = 7;
/// The SDK's packet cap (TXPACKET_MAX_LEN/RXPACKET_MAX_LEN); the decoder's default limit.
pub const MAX_PACKET_LEN: usize = 1024;
/// Size of a status packet with `n` data bytes and no stuffing: 11 + n.
pub const fn status_packet_len(n: usize) -> usize {
    PREFIX_LEN + 4 + n
}
