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
//!
//! A port that fails for good (the adapter unplugged: EIO, a hang-up) is reopened by a helper
//! thread, with backoff (`REOPEN_FIRST` doubling to `REOPEN_MAX`), at the same path: give the
//! loop a stable one (`/dev/serial/by-id/...`, the simulated bench's link), since a replugged
//! adapter may come back as another ttyUSB. The helper does the open (which allocates and may
//! take milliseconds) and hands the new port over through a one-slot ring; the loop thread
//! only pops it, once per cycle while the link is down, so it never blocks, sleeps or
//! allocates for a reopen. The dead port is handed to the helper to be closed there.
use crate::bus::Transport;
use crate::clock::monotonic_ns;
use crate::shared::LinkStats;
use dxl::serial::SerialPort;
use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// The first reopen waits this long after the loss, the next ones twice as long each time...
const REOPEN_FIRST: Duration = Duration::from_millis(50);
/// ...up to this.
const REOPEN_MAX: Duration = Duration::from_secs(1);

pub struct SerialTransport {
    port: Option<SerialPort>,
    write_timeout_ns: u64,
    reopen: Reopener,
}

impl SerialTransport {
    /// Opens `path` at `baud`; returns the transport and the warnings about its setup. `link`
    /// gets the reopen helper's counts and errors.
    pub fn open(path: &str, baud: u32, write_timeout_ns: u64, link: Arc<LinkStats>) -> io::Result<(SerialTransport, Vec<String>)> {
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
        let reopen = Reopener::spawn(path.to_string(), baud, link)?;
        Ok((SerialTransport { port: Some(port), write_timeout_ns, reopen }, warnings))
    }
}

/// What the loop thread and the reopen helper pass each other: one slot each way.
struct Handover {
    wanted: AtomicBool,
    shutdown: AtomicBool,
    /// helper → loop: the reopened port.
    fresh: Mutex<Option<SerialPort>>,
    /// loop → helper: the dead port, to be closed off the loop thread.
    dead: Mutex<Option<SerialPort>>,
}

struct Reopener {
    handover: Arc<Handover>,
    helper: Option<JoinHandle<()>>,
}

impl Reopener {
    fn spawn(path: String, baud: u32, link: Arc<LinkStats>) -> io::Result<Reopener> {
        let handover = Arc::new(Handover {
            wanted: AtomicBool::new(false),
            shutdown: AtomicBool::new(false),
            fresh: Mutex::new(None),
            dead: Mutex::new(None),
        });
        let theirs = handover.clone();
        let helper = std::thread::Builder::new()
            .name("admittance-reopen".into())
            .spawn(move || reopen_helper(&theirs, &path, baud, &link))?;
        Ok(Reopener { handover, helper: Some(helper) })
    }

    /// Hands the dead port over and asks for a new one; never blocks (a busy slot keeps the
    /// port here, and the next `take` hands it over).
    fn request(&self, dead: Option<SerialPort>) {
        if let Some(port) = dead {
            if let Ok(mut slot) = self.handover.dead.try_lock() {
                *slot = Some(port);
            } // else: dropped here; a close is a syscall, and this happens once per loss
        }
        self.handover.wanted.store(true, Ordering::Release);
        if let Some(helper) = &self.helper {
            helper.thread().unpark();
        }
    }

    /// The reopened port, if the helper has one ready; never blocks.
    fn take(&self) -> Option<SerialPort> {
        self.handover.fresh.try_lock().ok()?.take()
    }
}

impl Drop for Reopener {
    fn drop(&mut self) {
        self.handover.shutdown.store(true, Ordering::Release);
        if let Some(helper) = self.helper.take() {
            helper.thread().unpark();
            let _ = helper.join();
        }
    }
}

/// The helper: idle until a reopen is wanted, then tries with backoff until it has a port for
/// the loop to take (or is shut down).
fn reopen_helper(h: &Handover, path: &str, baud: u32, link: &LinkStats) {
    while !h.shutdown.load(Ordering::Acquire) {
        if let Some(dead) = h.dead.lock().ok().and_then(|mut slot| slot.take()) {
            drop(dead);
        }
        if !h.wanted.load(Ordering::Acquire) {
            std::thread::park();
            continue;
        }
        let mut wait = REOPEN_FIRST;
        while h.wanted.load(Ordering::Acquire) && !h.shutdown.load(Ordering::Acquire) {
            std::thread::park_timeout(wait);
            if h.shutdown.load(Ordering::Acquire) {
                return;
            }
            link.reopen_attempts.fetch_add(1, Ordering::Relaxed);
            match SerialPort::open(path, baud) {
                Ok(port) => {
                    if let Ok(mut slot) = h.fresh.lock() {
                        *slot = Some(port);
                    }
                    h.wanted.store(false, Ordering::Release);
                }
                Err(e) => {
                    link.reopen_failures.fetch_add(1, Ordering::Relaxed);
                    link.note_error(format!("reopening {path}: {e}"));
                    wait = (wait * 2).min(REOPEN_MAX);
                }
            }
        }
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

/// A bare kind for the closed port: io::Error::new would allocate, and this runs in the cycle.
fn closed() -> io::Error {
    io::ErrorKind::NotConnected.into()
}

impl Transport for SerialTransport {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        let port = self.port.as_ref().ok_or_else(closed)?;
        if !writable_within(port.as_raw_fd(), self.write_timeout_ns)? {
            return Err(io::ErrorKind::TimedOut.into());
        }
        port.write_all(bytes)
    }

    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> io::Result<usize> {
        let port = self.port.as_ref().ok_or_else(closed)?;
        let left = deadline_ns.saturating_sub(monotonic_ns());
        port.read(buf, Instant::now() + Duration::from_nanos(left))
    }

    fn disconnect(&mut self) {
        self.reopen.request(self.port.take());
    }

    fn reconnect(&mut self) -> bool {
        if self.port.is_none() {
            self.port = self.reopen.take();
        }
        self.port.is_some()
    }
}
