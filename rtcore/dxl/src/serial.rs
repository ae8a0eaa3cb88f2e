//! A raw serial port opened and configured with libc: the only serial code the RT loop uses.
//!
//! Why not `serial2`/`serialport`: their timeouts are whole milliseconds (serial2) or they
//! pull in nix/udev and cannot set the FTDI low-latency flag; the loop needs sub-millisecond
//! read deadlines and one syscall per write. Design:
//! - `open(O_RDWR|O_NOCTTY|O_NONBLOCK)`, `cfmakeraw`, 8N1, `CLOCAL|CREAD`, then any baud via
//!   termios2/`BOTHER` (`TCGETS2`/`TCSETS2`), read back to report the rate actually set.
//! - FTDI low latency (`TIOCGSERIAL`/`TIOCSSERIAL`, `ASYNC_LOW_LATENCY`) best-effort, reported.
//! - A pseudo-terminal ignores baud and refuses some ioctls: tolerated, and reported in
//!   [`OpenReport`] instead of failing, so the mock bench runs on ptys.
//! - `read` polls (`ppoll`, nanosecond timeout) until an absolute deadline; `write_all` loops
//!   on short writes. Both retry on `EINTR` and allocate nothing.
//! - Exclusive: right after `open`, before any setting or byte can disturb another user of the
//!   line, the port takes `flock(LOCK_EX|LOCK_NB)` on the device (the lock pyserial's
//!   `exclusive=True` takes, so the Python readers and this port exclude each other) and sets
//!   `TIOCEXCL` (the kernel then refuses any further `open` by an unprivileged process). A
//!   port already held fails with one line naming the holder's pid, read from /proc/locks.
//!   `TIOCEXCL` outlives our descriptor on a tty that stays open elsewhere (a mock's pty), so
//!   `Drop` clears it (`TIOCNXCL`) before closing.
use std::ffi::CString;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::os::unix::fs::MetadataExt;
use std::time::{Duration, Instant};

/// The kernel's `struct serial_struct` (linux/serial.h); libc does not declare it.
#[repr(C)]
#[derive(Default)]
struct SerialStruct {
    kind: libc::c_int,
    line: libc::c_int,
    port: libc::c_uint,
    irq: libc::c_int,
    flags: libc::c_int,
    xmit_fifo_size: libc::c_int,
    custom_divisor: libc::c_int,
    baud_base: libc::c_int,
    close_delay: libc::c_ushort,
    io_type: libc::c_char,
    reserved_char: libc::c_char,
    hub6: libc::c_int,
    closing_wait: libc::c_ushort,
    closing_wait2: libc::c_ushort,
    iomem_base: *mut libc::c_uchar,
    iomem_reg_shift: libc::c_ushort,
    port_high: libc::c_uint,
    iomap_base: libc::c_ulong,
}

const ASYNC_LOW_LATENCY: libc::c_int = 1 << 13;

/// What `open` managed to configure. Only the raw-mode setup is mandatory; the rest is
/// reported so the caller can warn (a pty, for instance, has no baud and no FTDI latency).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OpenReport {
    /// The baud rate the driver reports after `TCSETS2`, `None` when it could not be set.
    pub baud_actual: Option<u32>,
    /// Why the baud rate was not set (e.g. a pty refusing `TCSETS2`), as errno text.
    pub baud_error: Option<String>,
    /// The FTDI low-latency flag is set.
    pub low_latency: bool,
    /// Why it is not (ENOTTY on ptys and non-serial devices).
    pub low_latency_error: Option<String>,
}

pub struct SerialPort {
    fd: OwnedFd,
    report: OpenReport,
}

impl Drop for SerialPort {
    fn drop(&mut self) {
        // SAFETY: an ioctl without argument on our own descriptor; fails harmlessly (EIO) on a
        // device that is gone. The flock goes with the descriptor.
        unsafe { libc::ioctl(self.fd.as_raw_fd(), libc::TIOCNXCL as _) };
    }
}

fn errno() -> io::Error {
    io::Error::last_os_error()
}

/// Run a libc call that returns -1 on error, retrying on EINTR.
fn retry(mut f: impl FnMut() -> libc::c_int) -> io::Result<libc::c_int> {
    loop {
        let r = f();
        if r >= 0 {
            return Ok(r);
        }
        let e = errno();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

fn with_context(e: io::Error, what: &str, path: &str) -> io::Error {
    io::Error::new(e.kind(), format!("{what} {path}: {e}"))
}

impl SerialPort {
    /// Open `path` raw at `baud` (any integer rate the driver accepts, e.g. 4_500_000).
    pub fn open(path: &str, baud: u32) -> io::Result<SerialPort> {
        let c_path = CString::new(path).map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "path contains NUL"))?;
        let raw = retry(|| unsafe { libc::open(c_path.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK | libc::O_CLOEXEC) })
            .map_err(|e| match e.raw_os_error() {
                // TIOCEXCL set by another process: the kernel refuses the open itself.
                Some(libc::EBUSY) => busy_error(path),
                _ => with_context(e, "cannot open", path),
            })?;
        // SAFETY: `raw` is a freshly opened descriptor that nothing else owns.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        claim_exclusive(fd.as_raw_fd(), path)?;
        set_raw_8n1(fd.as_raw_fd()).map_err(|e| with_context(e, "cannot configure", path))?;
        let (baud_actual, baud_error) = match set_baud(fd.as_raw_fd(), baud) {
            Ok(actual) => (Some(actual), None),
            Err(e) => (None, Some(e.to_string())),
        };
        let (low_latency, low_latency_error) = match set_low_latency(fd.as_raw_fd()) {
            Ok(()) => (true, None),
            Err(e) => (false, Some(e.to_string())),
        };
        // Drop bytes that arrived before we owned the line; once, at open, never per cycle.
        unsafe { libc::tcflush(fd.as_raw_fd(), libc::TCIOFLUSH) };
        Ok(SerialPort { fd, report: OpenReport { baud_actual, baud_error, low_latency, low_latency_error } })
    }

    pub fn report(&self) -> &OpenReport {
        &self.report
    }

    /// Write every byte, waiting (poll) while the kernel buffer is full.
    pub fn write_all(&self, mut bytes: &[u8]) -> io::Result<()> {
        while !bytes.is_empty() {
            let r = unsafe { libc::write(self.fd.as_raw_fd(), bytes.as_ptr().cast(), bytes.len()) };
            if r >= 0 {
                bytes = &bytes[r as usize..];
                continue;
            }
            let e = errno();
            match e.raw_os_error() {
                Some(libc::EINTR) => {}
                Some(libc::EAGAIN) => {
                    self.wait(libc::POLLOUT, None)?;
                }
                _ => return Err(e),
            }
        }
        Ok(())
    }

    /// Read what is available, waiting until `deadline` at most; `Ok(0)` means the deadline
    /// passed with nothing to read.
    pub fn read(&self, buf: &mut [u8], deadline: Instant) -> io::Result<usize> {
        loop {
            let r = unsafe { libc::read(self.fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
            if r > 0 {
                return Ok(r as usize);
            }
            if r == 0 {
                return Err(io::Error::new(io::ErrorKind::UnexpectedEof, "serial device closed"));
            }
            let e = errno();
            match e.raw_os_error() {
                Some(libc::EINTR) => continue,
                Some(libc::EAGAIN) => {}
                _ => return Err(e),
            }
            if !self.wait(libc::POLLIN, Some(deadline))? {
                return Ok(0);
            }
        }
    }

    /// Read with a relative timeout in microseconds.
    pub fn read_timeout_us(&self, buf: &mut [u8], timeout_us: u64) -> io::Result<usize> {
        self.read(buf, Instant::now() + Duration::from_micros(timeout_us))
    }

    /// Drop unread input (call between transactions only when a reply was abandoned).
    pub fn discard_input(&self) -> io::Result<()> {
        retry(|| unsafe { libc::tcflush(self.fd.as_raw_fd(), libc::TCIFLUSH) }).map(drop)
    }

    /// Wait for `events` until `deadline` (forever when `None`); false on timeout.
    fn wait(&self, events: libc::c_short, deadline: Option<Instant>) -> io::Result<bool> {
        let mut pfd = libc::pollfd { fd: self.fd.as_raw_fd(), events, revents: 0 };
        loop {
            let ts = match deadline {
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        return Ok(false);
                    }
                    Some(libc::timespec { tv_sec: left.as_secs() as libc::time_t, tv_nsec: left.subsec_nanos() as libc::c_long })
                }
                None => None,
            };
            let tsp = ts.as_ref().map_or(std::ptr::null(), |t| t as *const libc::timespec);
            let r = unsafe { libc::ppoll(&mut pfd, 1, tsp, std::ptr::null()) };
            if r > 0 {
                if pfd.revents & (libc::POLLERR | libc::POLLNVAL | libc::POLLHUP) != 0 && pfd.revents & events == 0 {
                    return Err(io::Error::new(io::ErrorKind::BrokenPipe, "serial device hung up or failed"));
                }
                return Ok(true);
            }
            if r == 0 {
                return Ok(false);
            }
            let e = errno();
            if e.kind() != io::ErrorKind::Interrupted {
                return Err(e);
            }
        }
    }
}

impl AsRawFd for SerialPort {
    fn as_raw_fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }
}

/// Takes the device for this descriptor alone: `flock` (advisory, shared with pyserial's
/// `exclusive=True`), then `TIOCEXCL` (kernel-enforced for unprivileged openers; a non-tty
/// refuses it, which is not an error).
fn claim_exclusive(fd: RawFd, path: &str) -> io::Result<()> {
    if let Err(e) = retry(|| unsafe { libc::flock(fd, libc::LOCK_EX | libc::LOCK_NB) }) {
        return Err(if e.raw_os_error() == Some(libc::EWOULDBLOCK) { busy_error(path) } else { with_context(e, "cannot lock", path) });
    }
    // SAFETY: an ioctl without argument on our own descriptor.
    unsafe { libc::ioctl(fd, libc::TIOCEXCL as _) };
    Ok(())
}

/// "… is in use by another process (pid N)": the one line a second daemon on the same bus gets.
fn busy_error(path: &str) -> io::Error {
    let holder = lock_holder(path).map_or_else(String::new, |pid| format!(" (pid {pid})"));
    let message = format!("cannot open {path}: it is in use by another process{holder}; is another daemon running on it?");
    io::Error::new(io::Error::from_raw_os_error(libc::EBUSY).kind(), message)
}

/// The pid holding a `flock` on `path`'s device node, from /proc/locks (`N: FLOCK ADVISORY
/// WRITE pid MAJ:MIN:INODE 0 EOF`, device numbers in hex); `None` when nobody does or it
/// cannot be told.
pub fn lock_holder(path: &str) -> Option<u32> {
    let meta = std::fs::metadata(path).ok()?;
    let (major, minor, inode) = (libc::major(meta.dev()), libc::minor(meta.dev()), meta.ino());
    let text = std::fs::read_to_string("/proc/locks").ok()?;
    text.lines().find_map(|line| {
        let fields: Vec<&str> = line.split_whitespace().collect();
        // A waiter's line has "->" after the number; holders have FLOCK in the second field.
        if fields.get(1) != Some(&"FLOCK") {
            return None;
        }
        let mut id = fields.get(5)?.split(':');
        let maj = u32::from_str_radix(id.next()?, 16).ok()?;
        let min = u32::from_str_radix(id.next()?, 16).ok()?;
        let ino: u64 = id.next()?.parse().ok()?;
        if (maj, min, ino) != (major, minor, inode) {
            return None;
        }
        fields.get(4)?.parse().ok()
    })
}

fn set_raw_8n1(fd: RawFd) -> io::Result<()> {
    // SAFETY: termios is plain data; tcgetattr fills it.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    retry(|| unsafe { libc::tcgetattr(fd, &mut t) })?;
    unsafe { libc::cfmakeraw(&mut t) };
    t.c_cflag &= !(libc::CSIZE | libc::CSTOPB | libc::PARENB | libc::CRTSCTS);
    t.c_cflag |= libc::CS8 | libc::CLOCAL | libc::CREAD;
    t.c_iflag &= !(libc::IXON | libc::IXOFF | libc::IXANY);
    // VMIN=1 with O_NONBLOCK: "no data" is EAGAIN, so a 0-byte read really means hang-up.
    t.c_cc[libc::VMIN] = 1;
    t.c_cc[libc::VTIME] = 0;
    retry(|| unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) }).map(drop)
}

/// Any integer baud through termios2/BOTHER; returns the rate the driver reports back.
fn set_baud(fd: RawFd, baud: u32) -> io::Result<u32> {
    // SAFETY: termios2 is plain data; TCGETS2 fills it.
    let mut t: libc::termios2 = unsafe { std::mem::zeroed() };
    retry(|| unsafe { libc::ioctl(fd, libc::TCGETS2 as _, &mut t) })?;
    t.c_cflag &= !(libc::CBAUD | (libc::CBAUD << libc::IBSHIFT));
    t.c_cflag |= libc::BOTHER | (libc::BOTHER << libc::IBSHIFT);
    t.c_ispeed = baud;
    t.c_ospeed = baud;
    retry(|| unsafe { libc::ioctl(fd, libc::TCSETS2 as _, &t) })?;
    retry(|| unsafe { libc::ioctl(fd, libc::TCGETS2 as _, &mut t) })?;
    Ok(t.c_ospeed)
}

fn set_low_latency(fd: RawFd) -> io::Result<()> {
    let mut s = SerialStruct { iomem_base: std::ptr::null_mut(), ..Default::default() };
    retry(|| unsafe { libc::ioctl(fd, libc::TIOCGSERIAL as _, &mut s) })?;
    s.flags |= ASYNC_LOW_LATENCY;
    retry(|| unsafe { libc::ioctl(fd, libc::TIOCSSERIAL as _, &s) }).map(drop)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pty pair: the master end, and the slave's path.
    fn pty() -> (OwnedFd, String) {
        let mut master = 0;
        let mut slave = 0;
        let mut name = [0 as libc::c_char; 64];
        let r = unsafe { libc::openpty(&mut master, &mut slave, name.as_mut_ptr(), std::ptr::null(), std::ptr::null()) };
        assert_eq!(r, 0, "openpty failed");
        unsafe { libc::close(slave) };
        let path = unsafe { std::ffi::CStr::from_ptr(name.as_ptr()) }.to_string_lossy().into_owned();
        (unsafe { OwnedFd::from_raw_fd(master) }, path)
    }

    #[test]
    fn round_trip_through_a_pty() {
        let (master, path) = pty();
        let port = SerialPort::open(&path, 4_500_000).unwrap();
        assert!(!port.report().low_latency, "a pty has no FTDI latency timer");
        let msg = [0xFF, 0xFF, 0xFD, 0x00, 0x0D, 0x0A, 0x11, 0x13, 0x03];
        port.write_all(&msg).unwrap();
        let mut got = [0u8; 16];
        let n = unsafe { libc::read(master.as_raw_fd(), got.as_mut_ptr().cast(), got.len()) };
        assert_eq!(&got[..n as usize], &msg, "raw mode must pass control bytes untouched");
        unsafe { libc::write(master.as_raw_fd(), msg.as_ptr().cast(), msg.len()) };
        let mut back = [0u8; 16];
        let mut total = 0;
        while total < msg.len() {
            let n = port.read_timeout_us(&mut back[total..], 1_000_000).unwrap();
            assert!(n > 0, "reply lost");
            total += n;
        }
        assert_eq!(&back[..total], &msg);
    }

    #[test]
    fn read_returns_zero_at_the_deadline() {
        let (_master, path) = pty();
        let port = SerialPort::open(&path, 1_000_000).unwrap();
        let mut buf = [0u8; 4];
        assert_eq!(port.read_timeout_us(&mut buf, 200).unwrap(), 0);
    }

    #[test]
    fn a_second_open_fails_naming_the_holder_and_leaves_the_first_untouched() {
        let (master, path) = pty();
        let first = SerialPort::open(&path, 1_000_000).unwrap();
        let err = SerialPort::open(&path, 1_000_000).err().expect("the second open must fail");
        let text = err.to_string();
        assert!(text.contains(&path) && text.contains("in use"), "{text}");
        assert!(text.contains(&format!("pid {}", std::process::id())), "{text}");
        assert_eq!(lock_holder(&path), Some(std::process::id()));
        // The first port still works, and once it is closed the device can be opened again.
        first.write_all(&[0x42]).unwrap();
        let mut got = [0u8; 4];
        assert_eq!(unsafe { libc::read(master.as_raw_fd(), got.as_mut_ptr().cast(), 4) }, 1);
        drop(first);
        assert_eq!(lock_holder(&path), None);
        SerialPort::open(&path, 1_000_000).unwrap();
    }

    #[test]
    fn a_missing_device_names_the_path() {
        let err = SerialPort::open("/dev/does-not-exist-dxl", 57600).err().unwrap();
        assert!(err.to_string().contains("/dev/does-not-exist-dxl"));
    }
}
