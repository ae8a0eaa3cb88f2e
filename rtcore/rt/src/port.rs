//! The bench's serial port as the loop's `Transport`, and what opening it taught us.
//!
//! `dxl::serial::SerialPort` reads against an `Instant`; the loop's deadlines are CLOCK_MONOTONIC
//! nanoseconds (the clock `Instant` also reads on Linux), converted here by their distance from
//! now. What the port could not configure (a pty has no baud rate; a non-FTDI device no low-latency
//! flag; an FTDI latency timer above 1 ms) becomes warnings, not errors: the loop still runs.
//!
//! Writes wait for room in the kernel buffer for at most `write_timeout_ns`: a bus whose other
//! end stopped reading (a stalled adapter, a mock that died) must cost the loop a counted bus
//! error per cycle, not block the RT thread, and with it `stop()`, forever.
use crate::bus::Transport;
use crate::clock::monotonic_ns;
use dxl::serial::SerialPort;
use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::time::{Duration, Instant};

pub struct SerialTransport {
    port: SerialPort,
    write_timeout_ns: u64,
}

impl SerialTransport {
    /// Opens `path` at `baud`; returns the transport and the warnings about its setup.
    pub fn open(path: &str, baud: u32, write_timeout_ns: u64) -> io::Result<(SerialTransport, Vec<String>)> {
        let port = SerialPort::open(path, baud)?;
        let report = port.report();
        let mut warnings = Vec::new();
        if let Some(e) = &report.baud_error {
            warnings.push(format!("{path}: baud rate {baud} not set ({e}); fine on a pseudo-terminal"));
        }
        if let Some(timer) = ftdi_latency_timer_ms(path) {
            if timer > 1 {
                warnings.push(format!(
                    "{path}: FTDI latency_timer is {timer} ms, so every reply waits up to {timer} ms; \
                     write 1 to its latency_timer (see systemd/ for the udev rule)"
                ));
            }
        }
        Ok((SerialTransport { port, write_timeout_ns }, warnings))
    }
}

/// Whether `fd` can take bytes within `timeout_ns` (poll for POLLOUT, retried on EINTR).
fn writable_within(fd: RawFd, timeout_ns: u64) -> io::Result<bool> {
    let mut pfd = libc::pollfd { fd, events: libc::POLLOUT, revents: 0 };
    let ts = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: one valid pollfd, a valid timespec, no signal mask.
        let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if r >= 0 {
            return Ok(r > 0);
        }
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

/// The USB-serial latency timer of a ttyUSB device, when it has one.
fn ftdi_latency_timer_ms(path: &str) -> Option<u32> {
    let real = std::fs::canonicalize(path).ok()?;
    let name = real.file_name()?.to_str()?;
    let text = std::fs::read_to_string(format!("/sys/bus/usb-serial/devices/{name}/latency_timer")).ok()?;
    text.trim().parse().ok()
}

impl Transport for SerialTransport {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        if !writable_within(self.port.as_raw_fd(), self.write_timeout_ns)? {
            // A bare kind: io::Error::new would allocate, and this runs in the cycle.
            return Err(io::ErrorKind::TimedOut.into());
        }
        self.port.write_all(bytes)
    }

    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> io::Result<usize> {
        let left = deadline_ns.saturating_sub(monotonic_ns());
        self.port.read(buf, Instant::now() + Duration::from_nanos(left))
    }
}
