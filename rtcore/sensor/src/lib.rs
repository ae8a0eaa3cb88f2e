//! Force-sensor readers that feed the RT loop's sample ring without Python (issue 18).
//!
//! - [`optoforce`]: the OptoForce DAQ wire format: frame sync, checksum, status and overload
//!   bits, counts → newtons, the start-up configuration packet.
//! - [`slcan`]: the Lawicel ASCII protocol of USB-CAN adapters, host side.
//! - [`socketcan`]: a Linux CAN_RAW socket, libc only.
//! - [`source`]: where the byte stream comes from (serial, slcan, SocketCAN).
//! - [`reader`]: the thread: policies, reopen with backoff, staleness, counters, events.
pub mod optoforce;
pub mod reader;
pub mod slcan;
pub mod socketcan;
pub mod source;
