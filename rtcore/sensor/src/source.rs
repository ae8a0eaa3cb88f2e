//! Where the OptoForce byte stream comes from: a serial port (the DAQ's USB CDC), an slcan
//! adapter on a serial port, or a SocketCAN interface. Each source opens its device (sending
//! the start-up commands), hands back stream bytes, and closes; the reader owns everything
//! else (parsing, policies, reopening). On CAN the sample bytes ride in consecutive 8-byte
//! data frames with one identifier (contracts/daemon.md), so a CAN source appends the payloads
//! of the frames with that identifier and counts the others.
use std::io;
use std::time::Duration;

use dxl::serial::SerialPort;

use crate::slcan::{self, CanFrame, LineDecoder};
use crate::socketcan::CanSocket;

/// The CAN side's counters (zero on the serial path), named as the Python CAN reader's.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CanStats {
    pub can_frames: u64,
    pub foreign_frames: u64,
    pub undecodable_frames: u64,
    pub refused_commands: u64,
}

pub trait Source: Send + Sync {
    /// Acquire the device and send its start-up commands; the error names the device.
    fn open(&mut self) -> Result<(), String>;
    /// Append stream bytes to `out`, waiting up to `timeout_us` for the first; Err = the device failed.
    fn read(&mut self, out: &mut Vec<u8>, timeout_us: u64) -> io::Result<()>;
    fn close(&mut self);
    /// The device in words, as the Python readers say it: `optoforce sensor on /dev/ttyACM0`.
    fn describe(&self) -> String;
    /// Which path runs: `rust-serial`, `rust-slcan` or `rust-socketcan`.
    fn path(&self) -> &'static str;
    fn can_stats(&self) -> CanStats {
        CanStats::default()
    }
}

const READ_CHUNK: usize = 4096;

fn read_serial(port: &SerialPort, out: &mut Vec<u8>, timeout_us: u64) -> io::Result<()> {
    let mut chunk = [0u8; READ_CHUNK];
    // Block for the first bytes (bounded, so a stop is seen), then take what is already there.
    let n = port.read_timeout_us(&mut chunk, timeout_us)?;
    out.extend_from_slice(&chunk[..n]);
    if n == READ_CHUNK {
        let more = port.read_timeout_us(&mut chunk, 0)?;
        out.extend_from_slice(&chunk[..more]);
    }
    Ok(())
}

/// An OptoForce DAQ on a serial port; `config_packet` (rate, filter, DAQ tare) is written
/// right after each open, and the DAQ's acknowledgement is checked in the stream.
pub struct SerialSource {
    pub path: String,
    pub baud: u32,
    pub config_packet: Option<Vec<u8>>,
    port: Option<SerialPort>,
}

impl SerialSource {
    pub fn new(path: &str, baud: u32, config_packet: Option<Vec<u8>>) -> Self {
        SerialSource { path: path.to_string(), baud, config_packet, port: None }
    }
}

impl Source for SerialSource {
    fn open(&mut self) -> Result<(), String> {
        let port = SerialPort::open(&self.path, self.baud).map_err(|e| format!("the OptoForce sensor port: {e}"))?;
        if let Some(packet) = &self.config_packet {
            port.write_all(packet).map_err(|e| format!("the OptoForce sensor port {}: cannot send the configuration: {e}", self.path))?;
        }
        self.port = Some(port);
        Ok(())
    }

    fn read(&mut self, out: &mut Vec<u8>, timeout_us: u64) -> io::Result<()> {
        match &self.port {
            Some(port) => read_serial(port, out, timeout_us),
            None => Err(io::Error::new(io::ErrorKind::NotConnected, "the port is closed")),
        }
    }

    fn close(&mut self) {
        self.port = None;
    }

    fn describe(&self) -> String {
        format!("optoforce sensor on {}", self.path)
    }

    fn path(&self) -> &'static str {
        "rust-serial"
    }
}

/// Which frames carry the sample bytes, and the counting of the rest.
#[derive(Debug, Clone, Copy)]
pub struct CanFilter {
    pub can_id: u32,
    pub extended: bool,
}

impl CanFilter {
    fn take(&self, frame: &CanFrame, out: &mut Vec<u8>, stats: &mut CanStats) {
        if frame.id != self.can_id || frame.extended != self.extended || frame.remote {
            stats.foreign_frames += 1;
            return;
        }
        stats.can_frames += 1;
        out.extend_from_slice(&frame.data[..frame.len.min(8)]);
    }
}

/// An slcan (Lawicel) USB-CAN adapter on a serial port.
pub struct SlcanSource {
    pub port_path: String,
    pub tty_baud: u32,
    pub bitrate: Option<u32>,
    /// Seconds to wait after opening (adapters that reset when the port opens); 0 on a pty.
    pub open_delay: Duration,
    pub filter: CanFilter,
    port: Option<SerialPort>,
    decoder: LineDecoder,
    stats: CanStats,
}

impl SlcanSource {
    pub fn new(port_path: &str, tty_baud: u32, bitrate: Option<u32>, open_delay: Duration, filter: CanFilter) -> Result<Self, String> {
        slcan::open_sequence(bitrate)?; // an unknown bit rate fails at construction, not at each reopen
        Ok(SlcanSource { port_path: port_path.to_string(), tty_baud, bitrate, open_delay, filter, port: None, decoder: LineDecoder::default(), stats: CanStats::default() })
    }
}

impl Source for SlcanSource {
    fn open(&mut self) -> Result<(), String> {
        let port = SerialPort::open(&self.port_path, self.tty_baud).map_err(|e| format!("the CAN force sensor (slcan): {e}"))?;
        std::thread::sleep(self.open_delay);
        let sequence = slcan::open_sequence(self.bitrate)?;
        port.write_all(&sequence).map_err(|e| format!("the CAN force sensor (slcan) on {}: cannot open the channel: {e}", self.port_path))?;
        self.decoder.reset();
        self.port = Some(port);
        Ok(())
    }

    fn read(&mut self, out: &mut Vec<u8>, timeout_us: u64) -> io::Result<()> {
        let Some(port) = &self.port else { return Err(io::Error::new(io::ErrorKind::NotConnected, "the port is closed")) };
        let mut text = Vec::with_capacity(READ_CHUNK);
        read_serial(port, &mut text, timeout_us)?;
        let (filter, stats) = (self.filter, &mut self.stats);
        self.decoder.feed(&text, |frame| filter.take(&frame, out, stats));
        self.stats.undecodable_frames = self.decoder.stats.undecodable_frames;
        self.stats.refused_commands = self.decoder.stats.refused_commands;
        Ok(())
    }

    fn close(&mut self) {
        if let Some(port) = self.port.take() {
            let _ = port.write_all(slcan::CLOSE); // best effort: an unplugged adapter is closed anyway
        }
    }

    fn describe(&self) -> String {
        format!("can sensor on {}", self.port_path)
    }

    fn path(&self) -> &'static str {
        "rust-slcan"
    }

    fn can_stats(&self) -> CanStats {
        self.stats
    }
}

/// Frames read per call at most, so that stale checks and stops are seen in a flood.
const MAX_FRAMES_PER_READ: usize = 256;

/// A SocketCAN interface through a raw socket.
pub struct SocketCanSource {
    pub interface: String,
    pub filter: CanFilter,
    socket: Option<CanSocket>,
    stats: CanStats,
}

impl SocketCanSource {
    pub fn new(interface: &str, filter: CanFilter) -> Self {
        SocketCanSource { interface: interface.to_string(), filter, socket: None, stats: CanStats::default() }
    }
}

impl Source for SocketCanSource {
    fn open(&mut self) -> Result<(), String> {
        let socket = CanSocket::open(&self.interface, self.filter.can_id, self.filter.extended)
            .map_err(|e| format!("the CAN force sensor (socketcan): {e}"))?;
        self.socket = Some(socket);
        Ok(())
    }

    fn read(&mut self, out: &mut Vec<u8>, timeout_us: u64) -> io::Result<()> {
        let Some(socket) = &self.socket else { return Err(io::Error::new(io::ErrorKind::NotConnected, "the socket is closed")) };
        let mut timeout = timeout_us;
        for _ in 0..MAX_FRAMES_PER_READ {
            let Some(frame) = socket.recv(timeout)? else { break };
            self.filter.take(&frame, out, &mut self.stats);
            timeout = 0;
        }
        Ok(())
    }

    fn close(&mut self) {
        self.socket = None;
    }

    fn describe(&self) -> String {
        format!("can sensor on {}", self.interface)
    }

    fn path(&self) -> &'static str {
        "rust-socketcan"
    }

    fn can_stats(&self) -> CanStats {
        self.stats
    }
}
