//! Dynamixel Protocol 1.0 and 2.0 for the real-time path: codecs, the model table, the serial
//! port and a host-side client.
//!
//! Why hand-written rather than `dynamixel2`/`rustypot`: the RT loop must never allocate per
//! cycle, never `tcflush` per instruction and must read with deadlines far below 1 ms (one
//! control period). Encoders therefore write into caller buffers, decoders stream out of one
//! preallocated slab, the serial port polls with microsecond deadlines, and the [`client`]
//! keeps all its buffers from construction on.
//!
//! - [`crc`]: CRC-16 (0x8005, MSB-first, init 0).
//! - [`protocol2`], [`protocol1`]: encoders (`encode_*`) and streaming `Decoder`s.
//! - [`decoder`]: [`AnyDecoder`], either protocol chosen at run time.
//! - [`packet`]: the decoded [`Packet`], typed servo errors and codec errors.
//! - [`models`]: the control tables of the supported servos, shared with Python.
//! - [`serial`]: a raw tty opened with termios2 (any baud), `write_all`, deadline reads.
//! - [`client`]: ping/read/write/sync/bulk/reboot over a [`client::Transport`].
pub mod client;
pub mod crc;
pub mod decoder;
pub mod instruction;
pub mod models;
pub mod packet;
pub mod protocol1;
pub mod protocol2;
pub mod serial;
mod stream;

pub use crc::{crc16, crc16_update};
pub use decoder::AnyDecoder;
pub use packet::{BulkEntry, DecodeError, EncodeError, Kind, Packet, Protocol, ServoError};
