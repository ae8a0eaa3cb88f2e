//! The pseudo-terminal the simulated bus lives on.
//!
//! A pty is the one device every Dynamixel client can open unmodified (ROBOTIS's SDK, pyserial,
//! our own `dxl::serial`), so the mock looks like a USB adapter at `/dev/pts/N`.
//! Two details matter (docs: ../shared/docs/protocols.md §6):
//! - the slave is put in raw mode at once, before any client opens it: the default line
//!   discipline echoes, rewrites CR/LF and swallows XON/XOFF, which corrupts binary packets;
//! - the slave fd stays open for the mock's whole life: without it, reads on the master fail
//!   with EIO whenever no client has the port open (before the first open, after a close).
//!
//! The master is non-blocking: the bus thread multiplexes it with a timeout (`wait_readable`)
//! and must never block on a write when a client stops reading.
use std::ffi::CStr;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::time::Duration;

/// An open pseudo-terminal pair: the mock owns the master, clients open `path`.
pub struct Pty {
    master: OwnedFd,
    // Never read: holding it keeps the master readable when no client has the port open.
    _slave: OwnedFd,
    path: String,
}

impl Pty {
    /// Opens a pty pair, sets the slave raw and the master non-blocking.
    pub fn open() -> io::Result<Pty> {
        let (mut master, mut slave) = (-1, -1);
        // SAFETY: openpty writes two fds; name/termios/winsize may be null.
        let rc = unsafe {
            libc::openpty(&mut master, &mut slave, std::ptr::null_mut(), std::ptr::null(), std::ptr::null())
        };
        if rc != 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: both fds were just returned by openpty and are owned by nobody else.
        let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        set_raw(slave.as_raw_fd())?;
        set_raw(master.as_raw_fd())?;
        set_nonblocking(master.as_raw_fd())?;
        let path = tty_name(slave.as_raw_fd())?;
        Ok(Pty { master, _slave: slave, path })
    }

    /// The device path a client opens, e.g. `/dev/pts/7`.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Waits until the master has bytes to read or `timeout` passes (ns precision via ppoll).
    pub fn wait_readable(&self, timeout: Duration) -> io::Result<bool> {
        let mut pfd = libc::pollfd { fd: self.master.as_raw_fd(), events: libc::POLLIN, revents: 0 };
        let ts = libc::timespec {
            tv_sec: timeout.as_secs() as libc::time_t,
            tv_nsec: timeout.subsec_nanos() as libc::c_long,
        };
        // SAFETY: one valid pollfd, a valid timespec, no signal mask.
        let rc = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if rc < 0 {
            let err = io::Error::last_os_error();
            return if err.kind() == io::ErrorKind::Interrupted { Ok(false) } else { Err(err) };
        }
        Ok(rc > 0 && pfd.revents & libc::POLLIN != 0)
    }

    /// Reads what is available (0 when nothing is).
    pub fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        // SAFETY: buf is valid for buf.len() bytes.
        would_block_is_zero(unsafe { libc::read(self.master.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) })
    }

    /// Writes as much as the pty accepts now; returns how many bytes went out.
    pub fn write(&self, bytes: &[u8]) -> io::Result<usize> {
        // SAFETY: bytes is valid for bytes.len() bytes.
        would_block_is_zero(unsafe { libc::write(self.master.as_raw_fd(), bytes.as_ptr().cast(), bytes.len()) })
    }
}

/// A non-blocking read/write result: a byte count, with "try again" meaning 0 bytes.
fn would_block_is_zero(n: isize) -> io::Result<usize> {
    if n >= 0 {
        return Ok(n as usize);
    }
    let err = io::Error::last_os_error();
    match err.kind() {
        io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted => Ok(0),
        _ => Err(err),
    }
}

fn set_raw(fd: i32) -> io::Result<()> {
    // SAFETY: termios is plain data; tcgetattr fills it before use.
    let mut tio: libc::termios = unsafe { std::mem::zeroed() };
    // SAFETY: fd is an open tty and tio a valid termios.
    unsafe {
        if libc::tcgetattr(fd, &mut tio) != 0 {
            return Err(io::Error::last_os_error());
        }
        libc::cfmakeraw(&mut tio);
        if libc::tcsetattr(fd, libc::TCSANOW, &tio) != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok(())
}

fn set_nonblocking(fd: i32) -> io::Result<()> {
    // SAFETY: fcntl on an open fd with integer flags.
    unsafe {
        let flags = libc::fcntl(fd, libc::F_GETFL);
        if flags < 0 || libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) < 0 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok(())
}

fn tty_name(fd: i32) -> io::Result<String> {
    let mut buf = [0 as libc::c_char; 128];
    // SAFETY: buf is writable for its length; ttyname_r NUL-terminates on success.
    let rc = unsafe { libc::ttyname_r(fd, buf.as_mut_ptr(), buf.len()) };
    if rc != 0 {
        return Err(io::Error::from_raw_os_error(rc));
    }
    // SAFETY: ttyname_r succeeded, so buf holds a NUL-terminated string.
    let name = unsafe { CStr::from_ptr(buf.as_ptr()) };
    Ok(name.to_string_lossy().into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};

    #[test]
    fn bytes_cross_the_pty_unchanged_in_both_directions() {
        let pty = Pty::open().unwrap();
        assert!(pty.path().starts_with("/dev/pts/"));
        let mut client = std::fs::OpenOptions::new().read(true).write(true).open(pty.path()).unwrap();
        // Bytes a cooked tty would rewrite or swallow: CR, LF, XON, XOFF, ^C.
        let tricky = [0x0d, 0x0a, 0x11, 0x13, 0x03, 0xff, 0xfd];
        client.write_all(&tricky).unwrap();
        assert!(pty.wait_readable(Duration::from_secs(2)).unwrap());
        let mut buf = [0u8; 16];
        let n = pty.read(&mut buf).unwrap();
        assert_eq!(&buf[..n], &tricky);
        assert_eq!(pty.write(&tricky).unwrap(), tricky.len());
        let mut back = [0u8; 7];
        client.read_exact(&mut back).unwrap();
        assert_eq!(back, tricky);
    }

    #[test]
    fn master_stays_usable_after_a_client_closes() {
        let pty = Pty::open().unwrap();
        drop(std::fs::File::open(pty.path()).unwrap());
        let mut buf = [0u8; 4];
        assert_eq!(pty.read(&mut buf).unwrap(), 0);
        assert!(!pty.wait_readable(Duration::from_millis(1)).unwrap());
    }
}
