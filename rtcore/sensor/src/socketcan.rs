//! A Linux CAN_RAW socket on a SocketCAN interface (can0, vcan0...), with libc only.
//!
//! Why not the `socketcan` crate: it brings nix, embedded-can and more for three syscalls; the
//! kernel ABI used here (sockaddr_can, can_frame, can_filter) is fixed by linux/can.h. The
//! socket is bound to one interface with an acceptance filter on the sensor's identifier (the
//! kernel drops other traffic), is non-blocking, and is waited on with `ppoll` so a stop is
//! seen within the read timeout. An interface taken down makes `recv` fail (ENETDOWN): the
//! reader closes the socket and reopens it with backoff, as for an unplugged serial adapter.
use std::ffi::CString;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

use crate::slcan::CanFrame;

const CAN_RAW: libc::c_int = 1;
const SOL_CAN_RAW: libc::c_int = 101; // SOL_CAN_BASE (100) + CAN_RAW
const CAN_RAW_FILTER: libc::c_int = 1;
pub const CAN_EFF_FLAG: u32 = 0x8000_0000;
pub const CAN_RTR_FLAG: u32 = 0x4000_0000;
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
const CAN_EFF_MASK: u32 = 0x1FFF_FFFF;
const CAN_SFF_MASK: u32 = 0x7FF;

/// linux/can.h `struct sockaddr_can` (the address union is 16 bytes on every ABI).
#[repr(C)]
struct SockaddrCan {
    family: libc::sa_family_t,
    ifindex: libc::c_int,
    addr: [u64; 2],
}

/// linux/can.h `struct can_frame` (classic CAN, 16 bytes).
#[repr(C, align(8))]
#[derive(Default)]
struct RawFrame {
    can_id: u32,
    len: u8,
    pad: u8,
    res0: u8,
    len8_dlc: u8,
    data: [u8; 8],
}

#[repr(C)]
struct CanFilter {
    can_id: u32,
    can_mask: u32,
}

pub struct CanSocket {
    fd: OwnedFd,
}

fn errno_context(what: &str, interface: &str) -> io::Error {
    let e = io::Error::last_os_error();
    io::Error::new(e.kind(), format!("{what} {interface}: {e}"))
}

impl CanSocket {
    /// Bind a raw CAN socket to `interface`, accepting only frames with identifier `can_id`.
    pub fn open(interface: &str, can_id: u32, extended: bool) -> io::Result<CanSocket> {
        let name = CString::new(interface).map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "interface name contains NUL"))?;
        // SAFETY: plain syscalls on values we own; each result is checked.
        let raw = unsafe { libc::socket(libc::AF_CAN, libc::SOCK_RAW | libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC, CAN_RAW) };
        if raw < 0 {
            return Err(errno_context("cannot create a CAN socket for", interface));
        }
        // SAFETY: a fresh descriptor nothing else owns.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        let ifindex = unsafe { libc::if_nametoindex(name.as_ptr()) };
        if ifindex == 0 {
            return Err(errno_context("no CAN interface", interface));
        }
        let filter = if extended {
            CanFilter { can_id: can_id | CAN_EFF_FLAG, can_mask: CAN_EFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG }
        } else {
            CanFilter { can_id, can_mask: CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG }
        };
        let r = unsafe {
            libc::setsockopt(fd.as_raw_fd(), SOL_CAN_RAW, CAN_RAW_FILTER, (&filter as *const CanFilter).cast(), std::mem::size_of::<CanFilter>() as libc::socklen_t)
        };
        if r < 0 {
            return Err(errno_context("cannot set the CAN filter on", interface));
        }
        let addr = SockaddrCan { family: libc::AF_CAN as libc::sa_family_t, ifindex: ifindex as libc::c_int, addr: [0; 2] };
        let r = unsafe { libc::bind(fd.as_raw_fd(), (&addr as *const SockaddrCan).cast(), std::mem::size_of::<SockaddrCan>() as libc::socklen_t) };
        if r < 0 {
            return Err(errno_context("cannot bind to CAN interface", interface));
        }
        Ok(CanSocket { fd })
    }

    /// The next frame, waiting up to `timeout_us`; `Ok(None)` on timeout.
    pub fn recv(&self, timeout_us: u64) -> io::Result<Option<CanFrame>> {
        let mut raw = RawFrame::default();
        loop {
            let n = unsafe { libc::recv(self.fd.as_raw_fd(), (&mut raw as *mut RawFrame).cast(), std::mem::size_of::<RawFrame>(), 0) };
            if n == std::mem::size_of::<RawFrame>() as isize {
                return Ok(Some(frame_of(raw.can_id, raw.len, raw.data)));
            }
            if n >= 0 {
                return Err(io::Error::new(io::ErrorKind::InvalidData, format!("a CAN read of {n} bytes, not one can_frame")));
            }
            let e = io::Error::last_os_error();
            match e.raw_os_error() {
                Some(libc::EINTR) => continue,
                Some(libc::EAGAIN) => {}
                _ => return Err(e),
            }
            if timeout_us == 0 || !self.wait(timeout_us)? {
                return Ok(None);
            }
        }
    }

    fn wait(&self, timeout_us: u64) -> io::Result<bool> {
        let mut pfd = libc::pollfd { fd: self.fd.as_raw_fd(), events: libc::POLLIN, revents: 0 };
        let ts = libc::timespec { tv_sec: (timeout_us / 1_000_000) as libc::time_t, tv_nsec: ((timeout_us % 1_000_000) * 1000) as libc::c_long };
        let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if r < 0 {
            let e = io::Error::last_os_error();
            return if e.raw_os_error() == Some(libc::EINTR) { Ok(false) } else { Err(e) };
        }
        if r > 0 && pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0 && pfd.revents & libc::POLLIN == 0 {
            return Err(io::Error::new(io::ErrorKind::BrokenPipe, "the CAN interface went away"));
        }
        Ok(r > 0)
    }
}

/// A kernel `can_frame` as the reader's frame: the flag bits split off the identifier.
pub fn frame_of(can_id: u32, len: u8, data: [u8; 8]) -> CanFrame {
    let extended = can_id & CAN_EFF_FLAG != 0;
    let id = can_id & if extended { CAN_EFF_MASK } else { CAN_SFF_MASK };
    // An error frame is neither data nor remote: reported as remote so the reader drops it.
    let remote = can_id & (CAN_RTR_FLAG | CAN_ERR_FLAG) != 0;
    CanFrame { id, extended, remote, len: (len as usize).min(8), data }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kernel_structs_have_the_kernel_sizes() {
        assert_eq!(std::mem::size_of::<SockaddrCan>(), 24);
        assert_eq!(std::mem::size_of::<RawFrame>(), 16);
        assert_eq!(std::mem::size_of::<CanFilter>(), 8);
    }

    #[test]
    fn flags_split_from_the_identifier() {
        let f = frame_of(0x100, 8, [1; 8]);
        assert_eq!((f.id, f.extended, f.remote, f.len), (0x100, false, false, 8));
        let f = frame_of(CAN_EFF_FLAG | 0x1ABCDEF, 12, [0; 8]);
        assert_eq!((f.id, f.extended, f.len), (0x1ABCDEF, true, 8));
        assert!(frame_of(CAN_ERR_FLAG | 0x4, 8, [0; 8]).remote);
    }

    #[test]
    fn a_missing_interface_fails_with_its_name() {
        match CanSocket::open("nosuchcan7", 0x100, false) {
            Err(e) => assert!(e.to_string().contains("nosuchcan7"), "{e}"),
            Ok(_) => panic!("opened a CAN interface that does not exist"),
        }
    }
}
